"""A pybullet world from an occupancy map: occupied cells become static boxes.

Runs of occupied cells along a row are merged, then equal runs in consecutive rows, so
a map becomes a few hundred boxes instead of tens of thousands of cells.
"""
from __future__ import annotations

import numpy as np

from ..core.map_io import OccupancyMap

WALL_HEIGHT = 1.0   # m; the laser scans at 0.30 m


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


def add_map_walls(client, occupancy_map: OccupancyMap) -> int:
    """Static boxes for the map's occupied cells; returns how many."""
    import pybullet as p
    res = occupancy_map.resolution
    boxes = merge_cells_into_boxes(occupancy_map.occupied)
    if not boxes:
        return 0
    o = occupancy_map.origin
    quat = p.getQuaternionFromEuler([0, 0, o.yaw])
    # Pixel rectangle -> centre in the map frame (through the map's own conversion).
    centres_px = np.array([[(c0 + c1 - 1) / 2.0, (r0 + r1 - 1) / 2.0] for r0, c0, r1, c1 in boxes])
    centres = occupancy_map.frame.pixel_to_world(centres_px)
    for (r0, c0, r1, c1), (x, y) in zip(boxes, centres, strict=True):
        half = [(c1 - c0) * res / 2.0, (r1 - r0) * res / 2.0, WALL_HEIGHT / 2.0]
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        p.createMultiBody(0, shape, -1, [x, y, WALL_HEIGHT / 2.0], quat, physicsClientId=client)
    return len(boxes)
