"""The unmapped suite: a map that lacks part of what the robot sees - a SLAM run that
never covered the robot's surroundings, or a room it skipped. Scans are ray-cast in the
mapped world and localized against the map changed three ways: every wall within a
radius of the robot made unknown (as a map built without seeing them has it), the same
walls made free (a map that wrongly says there is nothing there), and a room beside the
robot made unknown, walls and floor (the robot outside it, at its edge). Where the map has
a place like the robot's that is fully mapped (a repeated wing), that place explains the
scan better than the true one; what a single scan cannot tell apart must not be answered
confidently."""
from __future__ import annotations

import numpy as np

from ..core.map_io import UNKNOWN, OccupancyMap, make_map
from ..core.transform import Rigid2D
from ..sim.laser import LaserConfig
from ..sim.raycast import sample_free_poses, simulate_scan
from .suites import Trial
from .tables import group, pct, secs, stats

RADII_M = (2.0, 4.0)
FREE_RADIUS_M = 2.0        # walls made free within this radius
ROOM_M = 3.0               # the unknown room: a square this wide, its near edge ROOM_GAP_M from the robot
ROOM_GAP_M = 0.5
# 270 deg / 20 m, 0.5 deg beams, 1 cm noise, 1% dropouts (the sim suite's laser)
LASER = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.01)


def unmapped_around(occupancy_map: OccupancyMap, pose: Rigid2D, radius_m: float) -> OccupancyMap:
    """The map with its occupied cells within radius_m of `pose` made unknown."""
    grid = occupancy_map.occupancy.copy()
    grid[near(occupancy_map, pose, radius_m) & occupancy_map.occupied] = UNKNOWN
    return make_map(grid, occupancy_map.resolution, occupancy_map.origin,
                    f'{occupancy_map.source} without its walls within {radius_m:g} m of {pose}')


def freed_around(occupancy_map: OccupancyMap, pose: Rigid2D, radius_m: float) -> OccupancyMap:
    """The map with its occupied cells within radius_m of `pose` made free."""
    grid = occupancy_map.occupancy.copy()
    grid[near(occupancy_map, pose, radius_m) & occupancy_map.occupied] = 0
    return make_map(grid, occupancy_map.resolution, occupancy_map.origin,
                    f'{occupancy_map.source} with its walls within {radius_m:g} m of {pose} made free')


def unknown_room_beside(occupancy_map: OccupancyMap, pose: Rigid2D) -> OccupancyMap:
    """The map with a ROOM_M square made unknown (walls and floor) ahead of the robot, its
    near edge ROOM_GAP_M in front of it: the robot outside the room, at its edge."""
    ahead, across = robot_frame_offsets(occupancy_map, pose)
    room = (ahead >= ROOM_GAP_M) & (ahead <= ROOM_GAP_M + ROOM_M) & (np.abs(across) <= ROOM_M / 2)
    grid = occupancy_map.occupancy.copy()
    grid[room] = UNKNOWN
    return make_map(grid, occupancy_map.resolution, occupancy_map.origin,
                    f'{occupancy_map.source} with a {ROOM_M:g} m room ahead of {pose} unknown')


def robot_frame_offsets(occupancy_map: OccupancyMap, pose: Rigid2D) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) each cell centre's offset from the robot, ahead (along its heading) and across."""
    cols, rows = np.meshgrid(np.arange(occupancy_map.width), np.arange(occupancy_map.height))
    xy = occupancy_map.frame.pixel_to_world(np.stack([cols.ravel(), rows.ravel()], axis=1))
    local = pose.inverse().apply(xy)
    return local[:, 0].reshape(cols.shape), local[:, 1].reshape(cols.shape)


def near(occupancy_map: OccupancyMap, pose: Rigid2D, radius_m: float) -> np.ndarray:
    """(H, W) cells whose centres lie within radius_m of the pose."""
    ahead, across = robot_frame_offsets(occupancy_map, pose)
    return np.hypot(ahead, across) <= radius_m


def unmapped_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Per map, seeded free poses; per pose one scan, localized against one cut map per
    radius, the walls made free instead, and an unknown room ahead."""
    trials = []
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + 500 + i)
        for pose in sample_free_poses(m, poses_per_map, rng, clearance=0.5):
            scan = simulate_scan(m, pose, LASER, rng=rng)
            cuts = [('walls unknown', radius, unmapped_around(m, pose, radius)) for radius in RADII_M] + \
                [('walls free', FREE_RADIUS_M, freed_around(m, pose, FREE_RADIUS_M)),
                 ('room unknown', ROOM_M, unknown_room_beside(m, pose))]
            for cut, size, own in cuts:
                trials.append(Trial('unmapped', name, {'cut': cut, 'unmapped_m': size, 'angle_step': 5}, pose,
                                    scan=scan, own_map=own))
    return trials


def unmapped_section(rows: list[dict]) -> list[str]:
    lines = ['## A map that lacks the robot\'s surroundings', '',
             'Ray-cast 270° / 20 m scans (1 cm noise, 1% dropouts) localized against the map with every wall '
             f'within {" or ".join(f"{r:g}" for r in RADII_M)} m of the robot made unknown, the walls within '
             f'{FREE_RADIUS_M:g} m made free instead, or a {ROOM_M:g} m room {ROOM_GAP_M:g} m ahead of the robot '
             'made unknown, walls and floor (`bench/unmapped.py`). "confident-wrong": says `success` but misses '
             '0.2 m / 5°; "twin named": the answer says its closest rival is the best turned by a half turn.', '',
             '| method | map change | size [m] | n | success 0.2 m/5° | confident | confident-wrong | twin named '
             '| median [s] | p95 [s] |', '|---|---|---|---|---|---|---|---|---|---|']
    for (method, cut, size), rr in sorted(group(rows, lambda r: (r['method'], r.get('cut', 'walls unknown'),
                                                                 r['unmapped_m'])).items()):
        s = stats(rr)
        twins = sum(bool(r.get('twin')) for r in rr) / max(len(rr), 1)
        lines.append(f'| {method} | {cut} | {size:g} | {s["n"]} | {pct(s["ok"])} | {pct(s["marked"])} '
                     f'| {pct(s["marked_wrong"])} | {pct(twins)} | {secs(s["median"])} | {secs(s["p95"])} |')
    return lines + ['']
