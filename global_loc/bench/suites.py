"""Trials of the three benchmark suites. A trial is one localization problem: a map, a
scan (or a local map's points), the true pose, and the condition it was made under.
All randomness is seeded, so the same command makes the same trials."""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from ..core.map_io import OccupancyMap, load_map_yaml
from ..core.paths import default_map_yaml
from ..core.scan import Scan, ScanPoints
from ..core.search_region import SearchRegion
from ..core.transform import Rigid2D
from ..io.carmen import LogGrid, read_flaser
from ..sim.laser import LaserConfig
from ..sim.raycast import points_cut_from_map, sample_free_poses
from ..sim.simulator import BASE_T_LASER, Simulator
from ..sim.synthetic_maps import aisles_with_a_box, symmetric_room
from .carmen import held_out_folds

THESIS_METHODS = ['template_ccoeff', 'template_sqdiff', 'features_orb', 'features_sift']
# features: ours, laser keypoints matched against views of the map (a proposer checked as the thesis's are)
METHODS = ['bnb'] + THESIS_METHODS + ['features']
# Δα only changes the template matchers; the others run once per scan.
ANGLE_STEP_METHODS = {'template_ccoeff', 'template_sqdiff'}


@dataclass
class Trial:
    suite: str
    map_name: str
    condition: dict               # e.g. {'fov': 270, 'range': 20, 'angle_step': 5, 'clutter': 0}
    truth: Rigid2D                # laser pose (suites 1, 3) or base pose (suite 2) in the map frame
    scan: Scan | None = None
    points: ScanPoints | None = None
    base_T_laser: Rigid2D = field(default_factory=Rigid2D)
    local_map_cells: int = 0      # suite 1: size of the cut
    region: SearchRegion | None = None   # prior suite: where the search may look
    own_map: OccupancyMap | None = None  # unmapped suite: the trial's own map (the map cut around the pose)


def shared_maps(shared_dir: str) -> dict[str, str]:
    """Real maps of shared/data/maps, by name (testmap is 10 x 10 cells: no room for a scan)."""
    maps_dir = os.path.join(shared_dir, 'maps')
    if not os.path.isdir(maps_dir):
        return {}
    names = ['willow-2010-02-18-0.10', 'building_31', 'tb3_sandbox', 'depot']
    paths = {n: os.path.join(maps_dir, f'{n}.yaml') for n in names}
    return {n: p for n, p in paths.items() if os.path.exists(p)}


def load_maps(shared_dir: str, quick: bool) -> dict[str, OccupancyMap]:
    paths = {'office': default_map_yaml(), **shared_maps(shared_dir)}
    if quick:
        paths = {k: v for k, v in paths.items() if k in ('office', 'willow-2010-02-18-0.10')}
    return {name: load_map_yaml(p) for name, p in paths.items()}


def cut_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Suite 1 (thesis §4.1): local maps cut from the map, radius 3 / 6 / 10 m, random
    rotation, Δα 5 and 15 deg."""
    trials = []
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + i)
        for pose in sample_free_poses(m, poses_per_map, rng):
            for radius in (3.0, 6.0, 10.0):
                points = points_cut_from_map(m, pose, radius)
                if len(points.points) < 20:
                    continue
                for step in (5.0, 15.0):
                    trials.append(Trial('cut', name, {'radius': radius, 'angle_step': step}, pose, points=points,
                                        local_map_cells=int((2 * radius / m.resolution) ** 2)))
    return trials


SIM_CONDITIONS = [   # one factor at a time around the thesis's 270 deg / 20 m / Δα 5 deg
    {'fov': 270, 'range': 20, 'angle_step': 5, 'clutter': 0},
    {'fov': 60, 'range': 20, 'angle_step': 5, 'clutter': 0},
    {'fov': 180, 'range': 20, 'angle_step': 5, 'clutter': 0},
    {'fov': 360, 'range': 20, 'angle_step': 5, 'clutter': 0},
    {'fov': 270, 'range': 4, 'angle_step': 5, 'clutter': 0},
    {'fov': 270, 'range': 20, 'angle_step': 15, 'clutter': 0},
    {'fov': 270, 'range': 20, 'angle_step': 5, 'clutter': 8},
    {'fov': 60, 'range': 4, 'angle_step': 5, 'clutter': 0},
]


def sim_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Suite 2 (thesis §4.2): pybullet Pioneer scans (0.01 m noise, 1% dropout) from seeded
    free poses; with clutter, 8 random objects not in the map (none within 1 m of the robot)."""
    trials = []
    for i, (name, m) in enumerate(maps.items()):
        poses = sample_free_poses(m, poses_per_map, np.random.default_rng(seed + 100 + i), clearance=0.5)
        plain = Simulator(m, seed=seed)
        try:
            for cond in SIM_CONDITIONS:
                for j, pose in enumerate(poses):
                    if cond['clutter']:
                        sim = Simulator(m, seed=seed + j)
                        sim.random_clutter(cond['clutter'], keep_clear_of=pose)
                    else:
                        sim = plain
                    sim.laser = LaserConfig(fov_deg=cond['fov'], num_beams=int(cond['fov'] * 2) + (cond['fov'] < 360),
                                            range_max=float(cond['range']))
                    sim.place(pose)
                    trials.append(Trial('sim', name, dict(cond), sim.true_pose(), scan=sim.scan(),
                                        base_T_laser=BASE_T_LASER))
                    if sim is not plain:
                        sim.close()
        finally:
            plain.close()
    return trials


def symmetric_maps() -> dict[str, OccupancyMap]:
    """Places one scan cannot tell apart: the four-fold room (nothing can), the store
    whose twin aisles a box behind the robot tells apart."""
    return {'symmetric_room': symmetric_room(), 'aisles_with_a_box': aisles_with_a_box()}


PRIOR_RADII = (0.0, 10.0, 4.0, 1.5)    # m; 0: no prior (the whole map)
PRIOR_METHODS = ('bnb', 'template_ccoeff')


def prior_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Search priors: pybullet 270 deg / 20 m scans at seeded free poses, each localized
    with no prior and within discs of PRIOR_RADII around a point up to half the radius
    from the truth (heading free), as a user's rough "it is in this room" would be."""
    trials = []
    laser = LaserConfig(fov_deg=270, num_beams=541, range_max=20.0)
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + 200 + i)
        sim = Simulator(m, laser, seed=seed)
        try:
            for pose in sample_free_poses(m, poses_per_map, rng, clearance=0.5):
                sim.place(pose)
                truth, scan = sim.true_pose(), sim.scan()
                for radius in PRIOR_RADII:
                    offset, direction = radius / 2 * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
                    center = Rigid2D(truth.x + offset * math.cos(direction), truth.y + offset * math.sin(direction))
                    trials.append(Trial('prior', name, {'prior_radius': radius, 'area_share': round(
                        math.pi * radius ** 2 / (m.free.sum() * m.resolution ** 2), 4) if radius else 1.0},
                        truth, scan=scan, base_T_laser=BASE_T_LASER, region=SearchRegion(center, radius)))
        finally:
            sim.close()
    return trials


def carmen_trials(shared_dir: str, scans_per_log: int, seed: int) -> tuple[list[Trial], dict, dict]:
    """Suite 3: real logs, 5 time-block folds; each held-out scan localized in the map of
    the other folds. Returns (trials, {map_key: OccupancyMap}, {log: filter counts})."""
    trials, maps, stats = [], {}, {}
    for log in ('intel', 'freiburg-079', 'aces'):
        path = os.path.join(shared_dir, 'carmen', f'{log}-corrected.log.gz')
        if not os.path.exists(path):
            continue
        records = read_flaser(path)
        fold_maps, kept, counts = held_out_folds(records, LogGrid(records, 0.05))
        rng = np.random.default_rng(seed)
        chosen = sorted(rng.choice(len(kept), size=min(scans_per_log, len(kept)), replace=False))
        counts['sampled'] = len(chosen)
        stats[log] = counts
        for k, m in fold_maps.items():
            maps[f'{log}/fold{k}'] = m
        for idx in chosen:
            h = kept[idx]
            trials.append(Trial('carmen', f'{log}/fold{h.fold}', {'log': log, 'angle_step': 5}, h.record.pose,
                                scan=h.record.scan))
    return trials, maps, stats
