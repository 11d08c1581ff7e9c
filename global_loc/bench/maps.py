"""The maps suite: which map am I on. Ray-cast scans at seeded free poses of each map,
localized in the run's maps as one set (core.map_set), and in a set of the same map twice
(two identical floors, where every answer must be `ambiguous`). Measured per scan: the
right map and pose, confident-wrong (a success on the wrong map or at the wrong pose),
the share answered on the wrong map, and the set's time against the scan's own map alone
(the cost of not knowing the map: at most N x with N maps)."""
from __future__ import annotations

import time

import numpy as np

from ..core.localizer import Localizer
from ..core.map_io import OccupancyMap
from ..core.map_set import MapSet
from ..core.transform import pose_correct
from ..sim.raycast import sample_free_poses, simulate_scan
from .tables import group, pct, secs
from .unmapped import LASER

TWINS = ('floor_1', 'floor_2')
COLUMNS = ('set', "scan's map", 'maps', 'n', 'right', 'confident', 'confident-wrong', 'on a wrong map',
           'own map alone: confident', 'median [s]', 'p95 [s]', 'time / own map (median)')


def maps_rows(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[dict]:
    """One row per scan and set: 'all' (every map of the run), 'twins' (the scan's map twice)."""
    localizers = {name: Localizer(m) for name, m in maps.items() if '/' not in name}   # not the CARMEN folds
    every = MapSet(localizers)
    rows = []
    for i, (name, loc) in enumerate(localizers.items()):
        rng = np.random.default_rng(seed + 700 + i)
        twins = MapSet({TWINS[0]: loc, TWINS[1]: loc})
        for pose in sample_free_poses(loc.map, poses_per_map, rng, clearance=0.5):
            scan = simulate_scan(loc.map, pose, rng=rng, **LASER)
            t0 = time.perf_counter()
            alone = loc.localize(scan)
            own_s = time.perf_counter() - t0
            for set_name, maps_set, right_maps in (('all', every, {name}), ('twins', twins, set(TWINS))):
                result = maps_set.localize(scan)
                right = result.pose is not None and result.map in right_maps and pose_correct(result.pose, pose)
                rows.append({'suite': 'map_set', 'kind': 'map_set', 'set': set_name, 'map': name,
                             'maps': len(maps_set.names), 'method': 'bnb', 'outcome': result.outcome.label,
                             'success': result.success, 'ok': right, 'answer_map': result.map,
                             'wrong_map': result.pose is not None and result.map not in right_maps,
                             'alone_success': alone.success, 'time_s': result.time_s, 'own_s': own_s,
                             'truth': [round(v, 4) for v in pose.as_tuple()]})
    return rows


def maps_section(rows: list[dict]) -> list[str]:
    """Per set and scan map: right map and pose, confident-wrong, wrong map, time against the own map."""
    lines = ['## Which map am I on (maps suite)', '',
             'Ray-cast 270° / 20 m scans (1 cm noise, 1% dropouts) at seeded free poses of each map, localized '
             'with bnb in a map set (`core/map_set.py`): "all", every map of the run; "twins", the scan\'s map '
             'twice (identical floors: a success there is a guess). "right": the right map and within 0.2 m / 5°; '
             '"confident-wrong": success on the wrong map or pose; "own map alone": the same scan localized in '
             'its map only (what the set adds: ratio of medians, N maps at most N×).', '',
             '| ' + ' | '.join(COLUMNS) + ' |', '|---' * len(COLUMNS) + '|']
    for (set_name, name), rr in sorted(group(rows, lambda r: (r['set'], r['map'])).items()):
        lines.append(table_line(set_name, name, rr))
    for set_name, rr in sorted(group(rows, lambda r: r['set']).items()):
        lines.append(table_line(set_name, 'every map', rr))
    return lines + ['']


def table_line(set_name: str, label: str, rr: list[dict]) -> str:
    n = len(rr)
    times, own = [r['time_s'] for r in rr], [r['own_s'] for r in rr]
    share = [pct(sum(f(r) for r in rr) / n) for f in (lambda r: r['ok'], lambda r: r['success'],
                                                      lambda r: r['success'] and not r['ok'],
                                                      lambda r: r['wrong_map'], lambda r: r['alone_success'])]
    return (f'| {set_name} | {label} | {rr[0]["maps"]} | {n} | ' + ' | '.join(share) +
            f' | {secs(float(np.median(times)))} | {secs(float(np.percentile(times, 95)))} '
            f'| {np.median(times) / max(np.median(own), 1e-9):.2f} |')
