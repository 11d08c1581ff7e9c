"""Small synthetic maps, each built for one property: no symmetry, four-fold symmetry,
twin aisles (with and without a telling box), twin rooms behind doors. For tests and the
benchmark's relocalization suite; all at 5 cm, origin (0, 0), row 0 at y = 0."""
import numpy as np

from ..core.map_io import from_occupancy_grid


def grid_map(grid, resolution: float = 0.05):
    """An OccupancyMap from rows of cell values, row 0 at y = 0 (OccupancyGrid order)."""
    grid = np.asarray(grid)
    return from_occupancy_grid(grid.shape[1], grid.shape[0], resolution, (0.0, 0.0, 0.0), grid.ravel())


def walled(rows: int, cols: int) -> np.ndarray:
    """A rows x cols grid of free cells inside a one-cell wall."""
    grid = np.zeros((rows, cols), dtype=int)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = 100
    return grid


def small_room():
    """A 4 x 3 m room at 5 cm with an L-shaped desk and a pillar: no symmetry."""
    grid = walled(60, 80)
    grid[10:14, 20:45] = 100
    grid[10:30, 41:45] = 100
    grid[40:44, 60:64] = 100
    return grid_map(grid)


def symmetric_room():
    """A 6 x 6 m square room with four identical pillars placed four-fold symmetrically."""
    grid = walled(120, 120)
    for r, c in ((30, 30), (30, 86), (86, 30), (86, 86)):
        grid[r:r + 4, c:c + 4] = 100
    return grid_map(grid)


def aisles():
    """A 12 x 6 m store at 5 cm: three identical 8 m shelves make two identical aisles, and
    the whole is symmetric under a half turn about its centre (6, 3)."""
    grid = walled(120, 240)
    for y in (1.5, 3.0, 4.5):
        grid[round(y / 0.05) - 3:round(y / 0.05) + 3, 40:200] = 100
    return grid_map(grid)


def twin_rooms(door_b_closed: bool, chair_in: str):
    """Two identical 4 x 3.5 m rooms (A left, B right) off one long featureless corridor,
    each with a door onto it; B's door may be closed, and a 0.3 m chair may stand in one."""
    res = 0.05
    w, h = int(24 / res), int(5.5 / res)
    grid = np.zeros((h, w), dtype=int)

    def occ(x0, x1, y0, y1, value=100):      # a box in metres (y up, row 0 at y = 0)
        grid[int(round(y0 / res)):int(round(y1 / res)), int(round(x0 / res)):int(round(x1 / res))] = value

    occ(0, 24, 0, 0.05), occ(0, 24, 5.45, 5.5), occ(0, 0.05, 0, 5.5), occ(23.95, 24, 0, 5.5)
    occ(0, 24, 2.0, 2.05)                                   # the rooms' wall onto the corridor
    for x in (2, 6, 16, 20):
        occ(x, x + 0.05, 2.0, 5.5)
    occ(3.6, 4.4, 2.0, 2.05, 0)                            # A's door
    if not door_b_closed:
        occ(17.6, 18.4, 2.0, 2.05, 0)                      # B's door
    cx = {'A': 5.0, 'B': 19.0}[chair_in]
    occ(cx, cx + 0.3, 4.2, 4.5)
    return grid_map(grid, res)


def aisles_with_a_box():
    """A 10 x 5 m store: shelves at x = 1, 3, ..., 9 m, so the aisles at x = 4 and 6 look
    alike from their ends within 2.5 m - and a box in the x = 4 aisle, 1.2 m below its top
    end, that a robot at that end sees only when it turns round."""
    grid = walled(100, 200)
    for x in (1, 3, 5, 7, 9):
        grid[20:80, round(x / 0.05) - 3:round(x / 0.05) + 3] = 100
    grid[60:68, 76:84] = 100
    return grid_map(grid)
