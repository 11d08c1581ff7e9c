"""How the package's nodes declare and read their parameters, nav2's way with numbers: a
double parameter accepts an integer (`max_search_s:=5`, `rate_hz: 5` in a params file,
`ros2 param set ... 5`) as the same double - it is declared with dynamic typing and read
back as a float - and a value of another kind (a string for a number) is one line naming
the parameter and its range, never a traceback."""
from __future__ import annotations

from typing import Optional

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException


class ParameterError(ValueError):
    """A parameter value a node cannot run with; the message names it and its range."""


def is_double(default) -> bool:
    return isinstance(default, float)


def describe(default, description: str, lo_hi: Optional[tuple] = None) -> ParameterDescriptor:
    """The descriptor: its range (integer or floating point, as the default), and dynamic
    typing for a double, so that an integer value is accepted (typed_value makes it one)."""
    d = ParameterDescriptor(description=description, dynamic_typing=is_double(default))
    if lo_hi is not None:
        lo, hi = lo_hi
        if isinstance(default, int) and not isinstance(default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        elif is_double(default):
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi))]
    return d


def typed_value(name: str, default, value, lo_hi: Optional[tuple] = None):
    """`value` as the parameter's type (an integer for a double: the same double) within
    lo_hi (inclusive); ParameterError naming the parameter otherwise."""
    expect = f' (a number in [{lo_hi[0]:g}, {lo_hi[1]:g}])' if lo_hi is not None else ''
    if is_double(default) or (isinstance(default, int) and not isinstance(default, bool)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                (not is_double(default) and not isinstance(value, int)):
            kind = 'a number' if is_double(default) else 'an integer'
            raise ParameterError(f'parameter {name}: {value!r} is not {kind}{expect}')
        value = float(value) if is_double(default) else value
        if lo_hi is not None and not (lo_hi[0] <= value <= lo_hi[1]):
            raise ParameterError(f'parameter {name}: {value} is outside [{lo_hi[0]}, {lo_hi[1]}]')
    return value


def declare(node, name: str, default, descriptor: ParameterDescriptor) -> Optional[str]:
    """Declare the parameter; the problem with the value it was started with, if any (then
    declared with its default: the node reports the problem instead of its constructor
    raising a traceback)."""
    try:
        node.declare_parameter(name, default, descriptor)
        return None
    except (InvalidParameterValueException, InvalidParameterTypeException) as e:
        node.declare_parameter(name, default, descriptor, ignore_override=True)
        return f'parameter {name}: {e}'
