"""The maps suite: which map am I on. Ray-cast scans at seeded free poses of each map,
localized in the run's maps as one set (core.map_set), and in a set of the same map twice
(two identical floors, where every answer must be `ambiguous`). Measured per scan: the
right map and pose, confident-wrong (a success on the wrong map or at the wrong pose),
the share answered on the wrong map, and the set's time against the scan's own map alone
(the cost of not knowing the map: at most N x with N maps), over sets of 1 to N maps.
Start-up from a stored pose (core.stored_pose): each confident answer stored, then a new
scan where the robot stands (kept), 0.5 m away (moved) or on another map (carried),
confirmed or searched in full - never confirmed wrong - against a full search's time."""
from __future__ import annotations

import time

import numpy as np

from ..core.localizer import Localizer
from ..core.map_io import OccupancyMap
from ..core.map_set import MapSet
from ..core.scan import scan_to_points
from ..core.stored_pose import SinceStored, confirm_stored_pose, stored_from_result
from ..core.transform import Rigid2D, pose_correct
from ..sim.raycast import sample_free_poses, simulate_scan
from .tables import group, pct, secs
from .unmapped import LASER

TWINS = ('floor_1', 'floor_2')
# A set's median time over the one-map median it should stay within (N maps: at most N): a
# map the scan does not fit is ruled out in a fraction of a search
SET_RATIO = 3.0
COLUMNS = ('set', "scan's map", 'maps', 'n', 'right', 'confident', 'confident-wrong', 'on a wrong map',
           'own map alone: confident', 'median [s]', 'p95 [s]', 'time / own map (median)')


def maps_rows(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[dict]:
    """One row per scan and set: 'all' (every map of the run), 'twins' (the scan's map twice);
    per scan, its time in sets of 1..N maps (kind maps_n) and its start-up cases (start_up)."""
    localizers = {name: Localizer(m) for name, m in maps.items() if '/' not in name}   # not the CARMEN folds
    every = MapSet(localizers)
    rows = []
    for i, (name, loc) in enumerate(localizers.items()):
        rng = np.random.default_rng(seed + 700 + i)
        twins = MapSet({TWINS[0]: loc, TWINS[1]: loc})
        for pose in sample_free_poses(loc.map, poses_per_map, rng, clearance=0.5):
            scan = simulate_scan(loc.map, pose, LASER, rng=rng)
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
                if set_name == 'all' and result.success:
                    rows += start_up_rows(every, result, name, pose, rng)
            rows += maps_n_rows(localizers, name, scan)
    return rows


def maps_n_rows(localizers: dict, name: str, scan) -> list[dict]:
    """The scan's time in sets of 1..N maps: its own map, then the others in the run's order."""
    order = [name] + [n for n in localizers if n != name]
    rows = []
    for n in range(1, len(order) + 1):
        result = MapSet({m: localizers[m] for m in order[:n]}).localize(scan)
        rows.append({'suite': 'map_set', 'kind': 'maps_n', 'map': name, 'maps': n, 'set_maps': order[:n],
                     'method': 'bnb',
                     'outcome': result.outcome.label, 'success': result.success, 'time_s': result.time_s})
    return rows


def start_up_rows(every: MapSet, result, name: str, pose: Rigid2D, rng) -> list[dict]:
    """The confident `result` stored; a new scan where the robot stands (kept), 0.5 m off it on
    a free cell (moved) and at a free pose of the next map (carried): the start-up's answer
    (confirmed, or the full search) against a full search on the same scan."""
    stored = stored_from_result(result, every.names, 0.0)
    names = every.names
    other = names[(names.index(name) + 1) % len(names)]
    cases = {'kept': (name, pose), 'carried': (other, sample_free_poses(every.localizers[other].map, 1, rng,
                                                                        clearance=0.5)[0])}
    here = every.localizers[name].map
    for a in rng.uniform(0, 2 * np.pi, 50):
        moved = Rigid2D(pose.x + 0.5 * np.cos(a), pose.y + 0.5 * np.sin(a), pose.yaw)
        if here.is_free_at(np.array([[moved.x, moved.y]]))[0]:
            cases['moved'] = (name, moved)
            break
    rows = []
    for case, (on, truth) in cases.items():
        points = scan_to_points(simulate_scan(every.localizers[on].map, truth, LASER, rng=rng))
        t0 = time.perf_counter()
        confirmed, _ = confirm_stored_pose(every, points, stored, Rigid2D(), SinceStored(0.0))
        answer = confirmed or every.localize_points(points)
        start_s = time.perf_counter() - t0
        full = every.localize_points(points)
        right = answer.pose is not None and answer.map == on and pose_correct(answer.pose, truth)
        rows.append({'suite': 'map_set', 'kind': 'start_up', 'case': case, 'map': name, 'maps': len(names),
                     'method': 'bnb', 'outcome': answer.outcome.label, 'success': answer.success, 'ok': right,
                     'confirmed': confirmed is not None, 'time_s': start_s, 'full_s': full.time_s,
                     'full_success': full.success, 'truth': [round(v, 4) for v in truth.as_tuple()]})
    return rows


def maps_section(rows: list[dict]) -> list[str]:
    """Per set and scan map: right map and pose, confident-wrong, wrong map, time against the
    own map; the time over 1..N maps; the start-up from a stored pose."""
    sets = [r for r in rows if r.get('kind', 'map_set') == 'map_set']
    lines = ['## Which map am I on (maps suite)', '',
             'Ray-cast 270° / 20 m scans (1 cm noise, 1% dropouts) at seeded free poses of each map, localized '
             'with bnb in a map set (`core/map_set.py`): "all", every map of the run; "twins", the scan\'s map '
             'twice (identical floors: a success there is a guess). "right": the right map and within 0.2 m / 5°; '
             '"confident-wrong": success on the wrong map or pose; "own map alone": the same scan localized in '
             'its map only (what the set adds: ratio of medians, N maps at most N×).', '',
             '| ' + ' | '.join(COLUMNS) + ' |', '|---' * len(COLUMNS) + '|']
    for (set_name, name), rr in sorted(group(sets, lambda r: (r['set'], r['map'])).items()):
        lines.append(table_line(set_name, name, rr))
    for set_name, rr in sorted(group(sets, lambda r: r['set']).items()):
        lines.append(table_line(set_name, 'every map', rr))
    return lines + [''] + targets_section(rows) + maps_n_section([r for r in rows if r.get('kind') == 'maps_n']) + \
        start_up_section([r for r in rows if r.get('kind') == 'start_up'])


def targets_section(rows: list[dict]) -> list[str]:
    """The suite's targets, met or not, from its rows."""
    every = [r for r in rows if r.get('kind', 'map_set') == 'map_set' and r['set'] == 'all']
    twins = [r for r in rows if r.get('kind', 'map_set') == 'map_set' and r['set'] == 'twins']
    by_n = group([r for r in rows if r.get('kind') == 'maps_n'], lambda r: r['maps'])
    start = group([r for r in rows if r.get('kind') == 'start_up'], lambda r: r['case'])
    if not every or not by_n or not start.get('kept'):
        return []
    right = sum(r['ok'] for r in every) / len(every)
    wrong = sum(r['success'] and not r['ok'] for r in every + twins)
    n = max(by_n)
    ratio = float(np.median([r['time_s'] for r in by_n[n]]) / np.median([r['time_s'] for r in by_n[1]]))
    kept = float(np.median([r['time_s'] / max(r['full_s'], 1e-9) for r in start['kept']]))
    confirmed_wrong = sum(r['confirmed'] and not r['ok'] for rr in start.values() for r in rr)
    checks = [(f'right map and pose over {every[0]["maps"]} maps ≥ 95%', pct(right), right >= 0.95),
              ('confident-wrong (both sets) = 0', str(wrong), wrong == 0),
              ('identical floors never confident', pct(sum(r['success'] for r in twins) / max(len(twins), 1)),
               not any(r['success'] for r in twins)),
              (f'time over {n} maps ≤ {min(n, SET_RATIO):g} × the one-map median', f'{ratio:.2f}×',
               ratio <= min(n, SET_RATIO)),
              ('start-up from a kept pose ≤ 10% of a full search (median)', f'{100 * kept:.1f}%', kept <= 0.1),
              ('a moved or carried robot never confirmed wrong', str(confirmed_wrong), confirmed_wrong == 0)]
    return ['### Targets', '', '| target | measured | |', '|---|---|---|'] + [
        f'| {name} | {value} | {"met" if ok else "not met"} |' for name, value, ok in checks] + ['']


def maps_n_section(rows: list[dict]) -> list[str]:
    """Time against the number of maps: each scan in its own map, then the others added."""
    if not rows:
        return []
    one = float(np.median([r['time_s'] for r in rows if r['maps'] == 1]))
    own = {m: float(np.median([r['time_s'] for r in rr])) for m, rr in
           group([r for r in rows if r['maps'] == 1], lambda r: r['map']).items()}
    lines = ['### Time against the number of maps', '',
             'Each scan in a set of its own map and the next N - 1 maps of the run. "/ one map": the median over '
             'the one-map median (the target: at most N). "/ its maps alone": the median over the median of, per '
             'scan, the sum of its set\'s maps\' one-map medians (what searching them one by one costs where the '
             'maps differ in size). Most of a set\'s time is proving, on each other map, that no place reaches '
             'the band below the best: on a large map that costs about what a search there costs whatever the '
             'scan, so against the one-map median (small maps\' scans dominate it) N× is not met, while against '
             'its maps searched alone the set costs less.', '',
             '| maps | n | confident | median [s] | p95 [s] | / one map (median) | at most N | / its maps alone |',
             '|---' * 8 + '|']
    for n, rr in sorted(group(rows, lambda r: r['maps']).items()):
        t = [r['time_s'] for r in rr]
        ratio = float(np.median(t)) / max(one, 1e-9)
        alone = float(np.median([sum(own[m] for m in r['set_maps']) for r in rr]))
        lines.append(f'| {n} | {len(rr)} | {pct(sum(r["success"] for r in rr) / len(rr))} | '
                     f'{secs(float(np.median(t)))} | {secs(float(np.percentile(t, 95)))} | {ratio:.2f} | '
                     f'{"met" if ratio <= n else "not met"} | {float(np.median(t)) / max(alone, 1e-9):.2f} |')
    return lines + ['']


def start_up_section(rows: list[dict]) -> list[str]:
    """Start-up from a stored pose: confirmed, right, confirmed-wrong, time against a full search."""
    if not rows:
        return []
    lines = ['### Start-up from a stored pose', '',
             'Each confident "all" answer stored (`core/stored_pose.py`); then a new scan where the robot stands '
             '("kept"), 0.5 m off it ("moved") or at a free pose of the next map ("carried"). The start-up tries '
             'the stored pose, and searches the set in full when the scan does not confirm it. "right": its answer '
             'is on the right map within 0.2 m / 5°; "confirmed-wrong": the stored pose confirmed at a wrong '
             'place; "/ full search": the median of the start-up\'s time over a full search\'s on the same scan '
             '(the target for kept: at most 10%).', '',
             '| case | n | confirmed | right | confirmed-wrong | start-up median [s] | full search median [s] '
             '| / full search (median) |', '|---' * 8 + '|']
    for case in ('kept', 'moved', 'carried'):
        rr = [r for r in rows if r['case'] == case]
        if not rr:
            continue
        n = len(rr)
        ratio = float(np.median([r['time_s'] / max(r['full_s'], 1e-9) for r in rr]))
        lines.append(f'| {case} | {n} | {pct(sum(r["confirmed"] for r in rr) / n)} | '
                     f'{pct(sum(r["ok"] for r in rr) / n)} | '
                     f'{pct(sum(r["confirmed"] and not r["ok"] for r in rr) / n)} | '
                     f'{secs(float(np.median([r["time_s"] for r in rr])))} | '
                     f'{secs(float(np.median([r["full_s"] for r in rr])))} | {ratio:.3f} |')
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
