#!/usr/bin/env python3
"""Writes maps/office.yaml + maps/office.pgm: the package's default map.

A 24 m x 16 m office floor at 5 cm cells: a corridor through the middle, five rooms of
unequal widths on either side with doors at unequal offsets, desks and cabinets placed
with a fixed seed, and a few pillars, so that most places look different from each
other (as in a real building) while a few corridor stretches stay alike. Outside the
building is unknown. Deterministic: re-running rewrites identical files.
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))
from global_loc.core.map_io import FREE, OCCUPIED, UNKNOWN, make_map, save_map_yaml  # noqa: E402
from global_loc.core.transform import Rigid2D  # noqa: E402

RES = 0.05
W, H, MARGIN = 24.0, 16.0, 1.0
WALL = 0.15


def main(out_dir):
    cols, rows = int((W + 2 * MARGIN) / RES), int((H + 2 * MARGIN) / RES)
    grid = np.full((rows, cols), UNKNOWN, dtype=np.int8)

    def box(x0, y0, x1, y1, value=OCCUPIED):
        """Fill [x0, x1] x [y0, y1] metres (building frame, y up)."""
        c0, c1 = int(round((x0 + MARGIN) / RES)), int(round((x1 + MARGIN) / RES))
        r0, r1 = rows - int(round((y1 + MARGIN) / RES)), rows - int(round((y0 + MARGIN) / RES))
        grid[max(r0, 0):max(r1, r0 + 1), max(c0, 0):max(c1, c0 + 1)] = value

    box(0, 0, W, H, FREE)
    for x0, y0, x1, y1 in [(0, 0, W, WALL), (0, H - WALL, W, H), (0, 0, WALL, H), (W - WALL, 0, W, H)]:
        box(x0, y0, x1, y1)
    corridor = (7.0, 9.0)
    box(0, corridor[0] - WALL, W, corridor[0])
    box(0, corridor[1], W, corridor[1] + WALL)
    rng = np.random.default_rng(20151)
    for widths, (ya, yb), door_wall in [([5.0, 4.0, 6.0, 3.5, 5.5], (0.0, corridor[0]), corridor[0] - WALL),
                                        ([6.0, 3.0, 4.5, 5.0, 5.5], (corridor[1], H), corridor[1])]:
        x = 0.0
        for i, w in enumerate(widths):
            if i > 0:
                box(x, ya, x + WALL, yb)                               # partition wall
            door = x + 0.6 + (0.37 * (i + 1) * w) % (w - 1.8)          # door offset differs per room
            box(door, door_wall, door + 0.9, door_wall + WALL, FREE)
            for _ in range(int(rng.integers(1, 4))):                  # desks / cabinets
                dw, dh = rng.choice([(1.6, 0.8), (0.8, 1.6), (1.2, 0.5), (0.5, 1.2)])
                fx = rng.uniform(x + 0.5, x + w - dw - 0.4)
                fy = rng.uniform(ya + 0.6, yb - dh - 0.6)
                box(fx, fy, fx + dw, fy + dh)
            x += w
    for px in (4.0, 11.5, 19.0):                                      # pillars by the corridor
        box(px, corridor[0] + 0.15, px + 0.3, corridor[0] + 0.45)
    box(21.0, 13.0, 23.0, 13.4)                                       # an L-shaped counter
    box(22.6, 11.0, 23.0, 13.0)

    occupancy_map = make_map(grid, RES, Rigid2D(-MARGIN, -MARGIN, 0.0), 'office')
    os.makedirs(out_dir, exist_ok=True)
    save_map_yaml(occupancy_map, os.path.join(out_dir, 'office.yaml'))
    print(f'wrote {out_dir}/office.yaml ({cols} x {rows} cells, {RES} m)')


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'maps'))
