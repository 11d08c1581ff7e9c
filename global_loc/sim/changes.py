"""A world that has changed since it was mapped: the map plus unmapped boxes (furniture),
people standing near the robot, and wall pieces gone (open doors, moved shelves) - what
a building looks like a week after its map was made. Scans are ray-cast in the changed
world and localized against the unchanged map (the benchmark's `changed` suite).

Three levels of change; every random choice comes from the caller's generator, so the
same seed makes the same world.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.map_io import OccupancyMap, make_map
from ..core.transform import Rigid2D


@dataclass(frozen=True)
class Change:
    """How much the world differs from its map: boxes per 100 m^2 of free floor (at least
    one), people within 0.6 - 3 m of the robot, wall pieces (0.8 m) removed per 100 m^2."""
    boxes_per_100m2: float
    people: int
    wall_gaps_per_100m2: float


LEVELS = {1: Change(2.0, 2, 1.0), 2: Change(5.0, 4, 2.5), 3: Change(10.0, 8, 5.0)}

BOX_SIDES_M = (0.3, 1.0)     # furniture: a box with sides drawn from this range
PERSON_RADIUS_M = 0.25
GAP_M = 0.8
ROBOT_CLEARANCE_M = 0.6      # nothing new closer than this to the robot's centre


def changed_world(occupancy_map: OccupancyMap, level: int, robot: Rigid2D, rng) -> OccupancyMap:
    """The map changed at `level` (1 .. 3, see LEVELS) around a robot at `robot`."""
    if level not in LEVELS:
        raise ValueError(f'change level must be one of {sorted(LEVELS)}, got {level}')
    change = LEVELS[level]
    grid = occupancy_map.occupancy.copy()
    res = occupancy_map.resolution
    area_100m2 = occupancy_map.free.sum() * res ** 2 / 100.0
    cols, rows = np.meshgrid(np.arange(grid.shape[1]), np.arange(grid.shape[0]))
    robot_col, robot_row = occupancy_map.frame.cell_of(np.array([[robot.x, robot.y]]))[0]
    robot_dist = np.hypot(cols - robot_col, rows - robot_row) * res
    remove_wall_pieces(grid, occupancy_map, max(1, round(change.wall_gaps_per_100m2 * area_100m2)), rng)
    free_rows, free_cols = np.nonzero(occupancy_map.free & (robot_dist > ROBOT_CLEARANCE_M + BOX_SIDES_M[1]))
    for _ in range(max(1, round(change.boxes_per_100m2 * area_100m2))):
        k = rng.integers(len(free_rows))
        w, h = rng.uniform(*BOX_SIDES_M, size=2) / res
        r0, c0 = free_rows[k], free_cols[k]
        grid[max(0, int(r0 - h / 2)):int(r0 + h / 2) + 1, max(0, int(c0 - w / 2)):int(c0 + w / 2) + 1] = 100
    near_rows, near_cols = np.nonzero(occupancy_map.free & (robot_dist > ROBOT_CLEARANCE_M) & (robot_dist < 3.0))
    for _ in range(change.people if len(near_rows) else 0):
        k = rng.integers(len(near_rows))
        grid[np.hypot(cols - near_cols[k], rows - near_rows[k]) * res <= PERSON_RADIUS_M] = 100
    grid[robot_dist <= ROBOT_CLEARANCE_M] = occupancy_map.occupancy[robot_dist <= ROBOT_CLEARANCE_M]
    return make_map(grid, res, occupancy_map.origin, f'{occupancy_map.source} changed (level {level})')


def remove_wall_pieces(grid: np.ndarray, occupancy_map: OccupancyMap, count: int, rng) -> None:
    """Clear `count` squares of GAP_M around occupied cells that face free space (a wall's
    surface, not its inside): doors opened, shelves moved."""
    occupied, free = occupancy_map.occupied, occupancy_map.free
    facing = occupied & (np.roll(free, 1, 0) | np.roll(free, -1, 0) | np.roll(free, 1, 1) | np.roll(free, -1, 1))
    rows, cols = np.nonzero(facing)
    half = max(1, round(GAP_M / occupancy_map.resolution / 2))
    for k in rng.choice(len(rows), size=min(count, len(rows)), replace=False) if len(rows) else []:
        window = (slice(max(0, rows[k] - half), rows[k] + half + 1), slice(max(0, cols[k] - half), cols[k] + half + 1))
        grid[window] = np.where(occupied[window], 0, grid[window])
