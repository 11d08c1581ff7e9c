"""The `scaling` suite: how bnb's time per localization and its per-map precomputation
grow with the map, beside the thesis method on the same scans.

One building (building_31, 5 cm) cut to 500^2 cells and tiled to 1000^2, 2000^2,
4000^2 and 6000^2 (36 Mcells); every tile gets its own random furniture (small boxes on free cells), so the
tiles are not copies of each other (copies would make every scan ambiguous). Scans: the
ray caster's 270 deg / 20 m, 0.01 m noise, 1% dropouts, at seeded free poses anywhere
in the map. The thesis method (rotated matchTemplate, CCOEFF, 5 deg) runs on the same
scans until one of its localizations takes a minute. Precomputation (time, the grids'
bytes, the process's memory growth) is measured in a fresh process per map, so that
nothing built before inflates or hides it; the real maps of the run are measured the
same way.
"""
from __future__ import annotations

import multiprocessing as mp
import time

import numpy as np

from ..core.localizer import Localizer
from ..core.map_io import OccupancyMap, make_map
from ..core.transform import Rigid2D, pose_correct
from ..sim.laser import LaserConfig
from ..sim.raycast import sample_free_poses, simulate_scan

SIZES = (500, 1000, 2000, 4000, 6000)
BASELINE_LIMIT_S = 60.0


def tiled_map(m: OccupancyMap, size: int, seed: int) -> OccupancyMap:
    """`m` tiled (or cut) to size x size cells, each tile with its own ~40 boxes of 3-8
    cells on free cells; cells past the last whole tile are unknown."""
    rng = np.random.default_rng(seed)
    tile = m.occupancy
    grid = np.full((size, size), -1, np.int8)
    for r0 in range(0, size, tile.shape[0]):
        for c0 in range(0, size, tile.shape[1]):
            part = tile[:size - r0, :size - c0].copy()
            free_r, free_c = np.nonzero((part >= 0) & (part < 35))
            for k in rng.choice(len(free_r), size=min(40, len(free_r)), replace=False):
                h, w = rng.integers(3, 9, size=2)
                part[free_r[k]:free_r[k] + h, free_c[k]:free_c[k] + w] = 100
            grid[r0:r0 + part.shape[0], c0:c0 + part.shape[1]] = part
    return make_map(grid, m.resolution, Rigid2D(), f'{m.source} tiled to {size}^2')


def _peak_rss_bytes() -> int:
    with open('/proc/self/status') as f:
        return next(int(line.split()[1]) * 1024 for line in f if line.startswith('VmHWM:'))


def _precompute_in_child(m: OccupancyMap) -> dict:
    from ..core.matchers.bnb import BranchAndBoundMatcher, warm_up
    warm_up()
    with open('/proc/self/clear_refs', 'w') as f:     # "5": reset the peak RSS to the current RSS
        f.write('5')
    before = _peak_rss_bytes()
    t = time.perf_counter()
    matcher = BranchAndBoundMatcher(m)
    seconds = time.perf_counter() - t
    return {'precompute_s': round(seconds, 2), 'grid_mb': round(matcher.stack.nbytes / 1e6, 1),
            'memory_mb': round((_peak_rss_bytes() - before) / 1e6, 1), 'peak_mb': round(_peak_rss_bytes() / 1e6, 1)}


def precompute_cost(m: OccupancyMap) -> dict:
    """bnb's precomputation for `m` in a fresh process: seconds, the grids' MB, and how
    far the process's peak memory rose above what it held before building."""
    with mp.get_context('spawn').Pool(1, maxtasksperchild=1) as pool:    # a child's error is raised here
        return pool.apply(_precompute_in_child, (m,))


def free_area_m2(m: OccupancyMap) -> float:
    return float(m.free.sum() * m.resolution ** 2)


def scaling_rows(building: OccupancyMap, real_maps: dict[str, OccupancyMap], poses: int, seed: int,
                 methods=('bnb', 'template_ccoeff'), sizes=SIZES) -> list[dict]:
    """One row per (size, pose, method) localization and one per map's precomputation."""
    rows, too_slow = [], set()
    for i, size in enumerate(sizes):
        m = tiled_map(building, size, seed + i)
        name = f'{size}^2'
        rows.append({'suite': 'scaling', 'kind': 'precompute', 'map': name, 'cells': size * size,
                     'free_m2': round(free_area_m2(m)), **precompute_cost(m)})
        rng = np.random.default_rng(seed + 1000 + i)
        truths = sample_free_poses(m, poses, rng, clearance=0.5)
        laser = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.01)
        scans = [simulate_scan(m, t, laser, rng=rng) for t in truths]
        loc = Localizer(m)
        for method in [k for k in methods if k not in too_slow]:
            for truth, scan in zip(truths, scans, strict=True):
                res = loc.localize(scan, method, 5.0)
                rows.append({'suite': 'scaling', 'kind': 'localize', 'map': name, 'free_m2': round(free_area_m2(m)),
                             'method': method, 'time_s': res.time_s, 'success': res.success,
                             'ok': res.pose is not None and pose_correct(res.pose, truth),
                             'ok_loose': res.pose is not None and pose_correct(res.pose, truth, 0.5, 10.0),
                             'outcome': res.outcome.label,
                             'expansions': getattr(res.search_stats, 'expansions', None)})
                if res.time_s > BASELINE_LIMIT_S:
                    too_slow.add(method)      # the rest of its scans, and larger maps, would take as long
                    break
        del loc, m
    for name, m in real_maps.items():
        rows.append({'suite': 'scaling', 'kind': 'precompute', 'map': name, 'cells': m.width * m.height,
                     'free_m2': round(free_area_m2(m)), **precompute_cost(m)})
    return rows
