"""A pybullet world from an occupancy map: occupied cells become static boxes.

Runs of occupied cells along a row are merged, then equal runs in consecutive rows, so
a map becomes a few hundred boxes instead of tens of thousands of cells.

For a 3D lidar the world is extruded in 3D (`obstacle_heights`): the building's walls
2.5 m high, and the map's other obstacles given heights, some low, so that a 16-ring
lidar sees a table only with its lower rings - and the floor where its rays hit it.
"""
from __future__ import annotations

import cv2
import numpy as np

from ..core.map_io import OccupancyMap

WALL_HEIGHT = 1.0   # m, every box of the 2D laser's world; the laser scans at 0.30 m
BUILDING_HEIGHT = 2.5       # m, the walls (the largest connected obstacle) and pillars of the 3D world
PILLAR_MAX_AREA_M2 = 0.1    # obstacles this small are pillars, floor to ceiling
FURNITURE_HEIGHTS = (0.7, 1.2)   # m, the other obstacles in turn: tables, cabinets


def obstacle_heights(occupancy_map: OccupancyMap) -> np.ndarray:
    """Per cell, the height of the obstacle on it (0: none): the largest 8-connected
    obstacle (the building's walls) and pillars BUILDING_HEIGHT, the other obstacles
    FURNITURE_HEIGHTS in turn (in the order connected components are labelled)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(occupancy_map.occupied.astype(np.uint8),
                                                               connectivity=8)
    heights = np.zeros(count)
    if count > 1:
        areas = stats[1:, cv2.CC_STAT_AREA] * occupancy_map.resolution ** 2
        building = 1 + int(np.argmax(areas))
        furniture = 0
        for label in range(1, count):
            if label == building or areas[label - 1] <= PILLAR_MAX_AREA_M2:
                heights[label] = BUILDING_HEIGHT
            else:
                heights[label] = FURNITURE_HEIGHTS[furniture % len(FURNITURE_HEIGHTS)]
                furniture += 1
    return heights[labels]


def merge_cells_into_boxes(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Rectangles (row0, col0, row1, col1), end-exclusive, covering exactly the True cells."""
    padded = np.zeros((occupied.shape[0], occupied.shape[1] + 2), dtype=np.int8)
    padded[:, 1:-1] = occupied
    d = np.diff(padded, axis=1)
    open_runs: dict[tuple[int, int], int] = {}     # (col0, col1) -> first row
    boxes = []
    for r in range(occupied.shape[0] + 1):
        runs = set()
        if r < occupied.shape[0]:
            starts = np.flatnonzero(d[r] == 1)
            ends = np.flatnonzero(d[r] == -1)
            runs = set(zip(starts.tolist(), ends.tolist(), strict=True))
        for run in list(open_runs):
            if run not in runs:
                boxes.append((open_runs.pop(run), run[0], r, run[1]))
        for run in runs:
            open_runs.setdefault(run, r)
    return boxes


def add_map_walls(client, occupancy_map: OccupancyMap, heights: np.ndarray | None = None) -> int:
    """Static boxes for the map's occupied cells, WALL_HEIGHT high or per cell `heights`
    (see obstacle_heights); returns how many."""
    if heights is None:
        return _add_boxes(client, occupancy_map, occupancy_map.occupied, WALL_HEIGHT)
    return sum(_add_boxes(client, occupancy_map, occupancy_map.occupied & (heights == h), float(h))
               for h in np.unique(heights[occupancy_map.occupied]))


def _add_boxes(client, occupancy_map: OccupancyMap, cells: np.ndarray, height: float) -> int:
    import pybullet as p
    res = occupancy_map.resolution
    boxes = merge_cells_into_boxes(cells)
    if not boxes:
        return 0
    o = occupancy_map.origin
    quat = p.getQuaternionFromEuler([0, 0, o.yaw])
    # Pixel rectangle -> centre in the map frame (through the map's own conversion).
    centres_px = np.array([[(c0 + c1 - 1) / 2.0, (r0 + r1 - 1) / 2.0] for r0, c0, r1, c1 in boxes])
    centres = occupancy_map.frame.pixel_to_world(centres_px)
    for (r0, c0, r1, c1), (x, y) in zip(boxes, centres, strict=True):
        half = [(c1 - c0) * res / 2.0, (r1 - r0) * res / 2.0, height / 2.0]
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        p.createMultiBody(0, shape, -1, [x, y, height / 2.0], quat, physicsClientId=client)
    return len(boxes)
