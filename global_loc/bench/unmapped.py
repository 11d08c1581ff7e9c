"""The unmapped suite: a map that lacks part of what the robot sees - a SLAM run that
never covered the robot's surroundings. Scans are ray-cast in the mapped world and
localized against the map with every wall within a radius of the robot made unknown (as
a map built without seeing them has it). Where the map has a place like the robot's that
is fully mapped (a repeated wing), that place explains the scan better than the true one;
what a single scan cannot tell apart must not be answered confidently."""
from __future__ import annotations

import numpy as np

from ..core.map_io import UNKNOWN, OccupancyMap, make_map
from ..core.transform import Rigid2D
from ..sim.raycast import sample_free_poses, simulate_scan
from .suites import Trial
from .tables import group, pct, secs, stats

RADII_M = (2.0, 4.0)
# 270 deg / 20 m, 0.5 deg beams, 1 cm noise, 1% dropouts (the sim suite's laser)
LASER = {'fov_deg': 270.0, 'num_beams': 541, 'range_max': 20.0, 'noise_std': 0.01, 'dropout': 0.01}


def unmapped_around(occupancy_map: OccupancyMap, pose: Rigid2D, radius_m: float) -> OccupancyMap:
    """The map with its occupied cells within radius_m of `pose` made unknown."""
    cols, rows = np.meshgrid(np.arange(occupancy_map.width), np.arange(occupancy_map.height))
    col, row = occupancy_map.frame.cell_of(np.array([[pose.x, pose.y]]))[0]
    near = np.hypot(cols - col, rows - row) * occupancy_map.resolution <= radius_m
    grid = occupancy_map.occupancy.copy()
    grid[near & occupancy_map.occupied] = UNKNOWN
    return make_map(grid, occupancy_map.resolution, occupancy_map.origin,
                    f'{occupancy_map.source} without its walls within {radius_m:g} m of {pose}')


def unmapped_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Per map, seeded free poses; per pose one scan and one cut map per radius."""
    trials = []
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + 500 + i)
        for pose in sample_free_poses(m, poses_per_map, rng, clearance=0.5):
            scan = simulate_scan(m, pose, rng=rng, **LASER)
            for radius in RADII_M:
                trials.append(Trial('unmapped', name, {'unmapped_m': radius, 'angle_step': 5}, pose, scan=scan,
                                    own_map=unmapped_around(m, pose, radius)))
    return trials


def unmapped_section(rows: list[dict]) -> list[str]:
    lines = ['## A map that lacks the robot\'s surroundings', '',
             'Ray-cast 270° / 20 m scans (1 cm noise, 1% dropouts) localized against the map with every wall '
             f'within {" or ".join(f"{r:g}" for r in RADII_M)} m of the robot made unknown (`bench/unmapped.py`). '
             '"confident-wrong": says `success` but misses 0.2 m / 5°.', '',
             '| method | radius [m] | n | success 0.2 m/5° | confident | confident-wrong | median [s] | p95 [s] |',
             '|---|---|---|---|---|---|---|---|']
    for (method, radius), rr in sorted(group(rows, lambda r: (r['method'], r['unmapped_m'])).items()):
        s = stats(rr)
        lines.append(f'| {method} | {radius:g} | {s["n"]} | {pct(s["ok"])} | {pct(s["marked"])} '
                     f'| {pct(s["marked_wrong"])} | {secs(s["median"])} | {secs(s["p95"])} |')
    return lines + ['']
