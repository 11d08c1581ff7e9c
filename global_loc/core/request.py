"""One localization request, validated once and with every default resolved, whoever asked
(an action goal, ~/trigger, nav2's ReinitializeGlobalLocalization, the health watch's own
relocalization). The server builds it first and the rest of the path reads only it: what
was asked cannot be re-interpreted further down.

Each per-request quantity has the bounds of the server parameter that gives its default
(a goal must not ask what the operator could not configure): core.limits holds them, for
the parameters' ranges too.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from . import limits
from .localizer import check_angle_step
from .matchers import resolve_method
from .search_region import SearchRegion
from .transform import Rigid2D

# request field -> (lowest, highest): the bounds of core.limits, by the fields' names.
BOUNDS = {
    'scan_timeout_s': limits.SCAN_TIMEOUT_S,
    'resolve_by_motion_s': limits.RESOLVE_BY_MOTION_S,
    'search_radius_m': limits.SEARCH_RADIUS_M,
    'search_yaw_tolerance_deg': limits.YAW_TOLERANCE_DEG,
}


ORIGIN = Rigid2D()


class RequestError(ValueError):
    """The request cannot be served as asked; the message says which field and why."""


@dataclass(frozen=True)
class Request:
    method: str                 # canonical matcher name
    angle_step_deg: float       # Δα of the template matcher
    scan_timeout_s: float
    region: SearchRegion
    resolve_by_motion_s: float = 0.0
    rotate_in_place: bool = False
    publish: bool = True
    publish_if_ambiguous: bool = False
    origin: str = 'goal'        # who asked: goal, trigger, reinitialize, relocalization, start-up
    maps: tuple = ()            # the maps to search, by name (a map set); empty: every map
    from_stored_pose: bool = False   # first try the stored pose (core.stored_pose), then search in full


@dataclass(frozen=True)
class RequestDefaults:
    """The server's current defaults for what a request leaves at 0 / empty."""
    method: str
    angle_step_deg: float
    scan_timeout_s: float


def check_bound(name: str, value: float) -> float:
    lo, hi = BOUNDS[name]
    if not (math.isfinite(value) and lo <= value <= hi):
        raise RequestError(f'{name} must be in [{lo:g}, {hi:g}], got {value}')
    return value


@dataclass(frozen=True)
class Asked:
    """A request as it was asked, before validation: an action goal's fields, or those of
    ~/trigger and the watch's relocalization (0 / '' leave a field to the server's default)."""
    origin: str = 'goal'        # who asked: goal, trigger, reinitialize, relocalization, start-up
    method: str = ''
    angle_step_deg: float = 0.0
    timeout_s: float = 0.0
    center: Rigid2D = ORIGIN
    radius_m: float = 0.0
    yaw_tolerance_deg: float = 0.0
    resolve_by_motion_s: float = 0.0
    rotate_in_place: bool = False
    publish: bool = True
    publish_if_ambiguous: bool = False
    maps: tuple = ()            # by name; empty: every map the server has
    from_stored_pose: bool = False


def make_request(asked: Asked, defaults: RequestDefaults) -> Request:
    """The request with 0 / '' replaced by the defaults and every field checked; RequestError
    (naming the field) otherwise. An unknown method or one this OpenCV build lacks is one."""
    try:
        name = resolve_method(asked.method or defaults.method)
        step = check_angle_step(asked.angle_step_deg or defaults.angle_step_deg)
        region = SearchRegion(asked.center, check_bound('search_radius_m', asked.radius_m),
                              math.radians(check_bound('search_yaw_tolerance_deg', asked.yaw_tolerance_deg)))
    except RequestError:
        raise
    except ValueError as e:      # MethodError, the angle step, a non-finite centre
        raise RequestError(str(e)) from None
    return Request(name, step, check_bound('scan_timeout_s', asked.timeout_s or defaults.scan_timeout_s), region,
                   check_bound('resolve_by_motion_s', asked.resolve_by_motion_s), bool(asked.rotate_in_place),
                   bool(asked.publish), bool(asked.publish_if_ambiguous), asked.origin, tuple(asked.maps),
                   bool(asked.from_stored_pose))
