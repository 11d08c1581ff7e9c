"""The bounds of every quantity a request or a map brings, in one place: the goal's
validation, the ROS parameters' ranges, the CLI and the matchers read them here, so a
goal field can never ask for what its parameter may not (once, an angle step of 1e-6
on a goal built 11-22 GB of arrays while the parameter was limited to 0.1-180).

Bounds are (lowest, highest), both allowed. A 0 that means "the default" or "no bound"
on a goal is the caller's to resolve before checking.
"""
from __future__ import annotations

import math

# Rotation step of the rotated-template matcher, degrees: 0.1 deg turns a 30 m return by
# 5 cm, one cell of a typical map - finer finds nothing new and costs 3600 rotations.
ANGLE_STEP_DEG = (0.1, 180.0)
# Search prior around a pose (0: the whole map). 100 km: a square map at the cell cap
# below and the coarsest resolution; a larger radius is the whole map anyway.
SEARCH_RADIUS_M = (0.0, 1e5)
# Heading window of the search prior, degrees (0: any heading; 180: any heading too).
YAW_TOLERANCE_DEG = (0.0, 180.0)
# How long a goal waits for a fresh scan, s (the server's scan_timeout_s, and a goal's timeout_s).
SCAN_TIMEOUT_S = (0.1, 600.0)
# Seconds a search may take before it answers "search incomplete" (max_search_s).
MAX_SEARCH_S = (0.01, 1e6)
# How long an ambiguous answer may be followed while the robot moves, s (0: not at all);
# ten minutes is beyond any turn or short drive that settles a twin.
RESOLVE_BY_MOTION_S = (0.0, 600.0)

# Map cell size, m. Below 1 mm a cell is far finer than any laser's range noise (~1 cm)
# and bnb's leaf angle step acos(1 - res^2 / 2 r^2) loses its digits (at 1e-8 m it is 0:
# a division by zero); above 10 m one cell holds a whole room and a scan has no shape.
MAP_RESOLUTION_M = (1e-3, 10.0)
# Cells in a map: 10 000 x 10 000 (1 km^2 at 10 cm). bnb's precomputation takes ~23 bytes a
# cell (286 MB of grids and +365 MB peak for 4000^2: docs/decisions/0011-the-planes-fit-a-memory-budget.md),
# so the cap keeps one map's grids to ~2.3 GB; a larger map is refused at load, not at the first goal.
MAX_MAP_CELLS = 100_000_000

# Working memory one goal's thesis matcher may allocate (template: the rotation angles,
# the local map, one rotation's canvas and its score image; features: the local map),
# computed up front from the request and refused before anything is allocated.
MATCH_BUDGET_BYTES = 1 << 30

# The primary laser's mounting on the base when no tf gives it (server laser_* parameters,
# the CLI's --laser-* flags): a position within 100 m, angles within one turn either way.
LASER_OFFSET_M = (-100.0, 100.0)
LASER_ANGLE_RAD = (-2 * math.pi, 2 * math.pi)

# Memory one thesis matcher's precomputation for a map may allocate (the map image blurred,
# or its keypoints and descriptors: SIFT builds a float pyramid of ~240 bytes a map cell,
# 3.8 GB at 4000 x 4000 - measured by peak RSS at 2000 x 2000, 236 B/cell). Estimated from the map's
# size and refused before building. bnb has its own budget (bnb.plane_memory_mb; its grids
# are bounded by MAX_MAP_CELLS).
BUILD_BUDGET_BYTES = 1 << 30

# A laser tilted by more than this (roll or pitch away from 0 and from 180 degrees) does
# not scan a horizontal plane: its ranges are not the map's distances.
MAX_LASER_TILT_DEG = 5.0


class BudgetError(ValueError):
    """A request would allocate more than its stated budget; the message says how much and why."""


def check_within(name: str, value: float, bounds: tuple[float, float], unit: str = '') -> float:
    """`value` when it is a number within `bounds`; ValueError naming `name` otherwise (NaN included)."""
    lo, hi = bounds
    try:
        ok = lo <= value <= hi
    except TypeError:
        ok = False
    if not ok:
        unit = f' {unit}' if unit else ''
        raise ValueError(f'{name} must be in [{lo:g}, {hi:g}]{unit}, got {value}')
    return value


def check_angle_step(angle_step_deg: float) -> float:
    """The rotated-template matcher's Δα within ANGLE_STEP_DEG; ValueError otherwise."""
    return check_within('angle step', angle_step_deg, ANGLE_STEP_DEG, 'degrees')


def check_budget(what: str, nbytes: float, remedy: str) -> None:
    """BudgetError unless `nbytes` (computed before allocating) fits MATCH_BUDGET_BYTES."""
    budget = MATCH_BUDGET_BYTES
    if not nbytes <= budget:
        raise BudgetError(f'{what} would need {format_bytes(nbytes)}, more than the per-goal budget of '
                          f'{format_bytes(budget)}; {remedy}')


def check_build_budget(what: str, nbytes: float, remedy: str) -> None:
    """BudgetError unless a matcher's precomputation (`nbytes`, estimated before building) fits
    BUILD_BUDGET_BYTES."""
    if not nbytes <= BUILD_BUDGET_BYTES:
        raise BudgetError(f'{what} would need about {format_bytes(nbytes)}, more than the budget of '
                          f'{format_bytes(BUILD_BUDGET_BYTES)} for one matcher\'s precomputation; {remedy}')


def format_bytes(nbytes: float) -> str:
    """'1.5 GB', '12 MB', '3 kB' (powers of 1024), or 'inf' bytes."""
    if not math.isfinite(nbytes):
        return f'{nbytes} bytes'
    for unit, size in (('GB', 1 << 30), ('MB', 1 << 20), ('kB', 1 << 10)):
        if nbytes >= size:
            return f'{nbytes / size:.3g} {unit}'
    return f'{int(nbytes)} bytes'
