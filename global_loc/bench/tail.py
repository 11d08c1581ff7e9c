"""The tail suite: bnb's slow end against its targets, one localization at a time on
every core (the server's case: one goal at a time). The changed world at its heaviest
level, the real logs, and the tiled building at 4000^2 and 6000^2 cells, each size in a
fresh process that builds it, prepares bnb, localizes and reports its peak memory.
The report is a table of the targets, met or not, with what the rows say of the cause."""
from __future__ import annotations

import multiprocessing as mp
from dataclasses import dataclass

import cv2
import numpy as np
from tqdm import tqdm

from ..core.localizer import Localizer
from ..core.map_io import OccupancyMap
from ..core.matchers.bnb import BranchAndBoundOptions
from ..core.transform import pose_correct
from ..sim.laser import LaserConfig
from ..sim.raycast import sample_free_poses, simulate_scan
from . import worker
from .changed import CHANGE_LEVELS, changed_trials
from .scaling import _peak_rss_bytes, tiled_map
from .suites import carmen_trials
from .tables import group, secs, time_quantiles

BIG_SIZES = (4000, 6000)
# What the map explains of a scan at a best score of 0.45 (verdict.explained_share): the
# verdict's least for a confident answer at the default min_confidence - a search stopped
# below it is proving a poor match, above it the scan was one the map explains
EXPLAINED_SCORE = 0.3 + 0.3 * BranchAndBoundOptions().min_confidence
MAX_NODES = BranchAndBoundOptions().max_nodes      # the rows are bnb at its defaults
LIMITS = {'changed_p95_s': 1.0, 'logs_median_s': 0.1, 'logs_p95_s': 0.5, 'big_p95_s': 1.5, 'peak_mb': 800.0}


@dataclass(frozen=True)
class TailSample:
    """What the tail suite draws: `poses` per map of the changed world (at its heaviest level;
    half as many, at least 3, on each tiled size), `scans_per_log` of each real log, all
    seeded by `seed`."""
    poses: int
    scans_per_log: int
    seed: int


def tail_rows(maps: dict[str, OccupancyMap], shared: str, building: OccupancyMap, sample: TailSample,
              threads: int, sizes=BIG_SIZES) -> list[dict]:
    """Rows of kind 'changed', 'carmen' (run_job's) and 'big' (one per localization, with
    its process's peak memory): the run's maps and data folder, the building tiled to each
    of `sizes`, localized on `threads` threads."""
    poses, seed = sample.poses, sample.seed
    world = {n: m for n, m in maps.items() if '/' not in n}
    trials = [t for t in changed_trials(world, poses, seed) if t.condition['change'] == CHANGE_LEVELS[-1]]
    carmen, carmen_maps, _ = carmen_trials(shared, sample.scans_per_log, seed)
    worker.worker_init({**world, **carmen_maps}, threads)
    rows = []
    for i, trial in enumerate(tqdm(trials + carmen, desc='tail: changed world and logs', unit='scan')):
        row = worker.run_job((i, trial, 'bnb'))
        rows.append({**row, 'suite': 'tail', 'kind': trial.suite, 'log': row.get('log', '')})
    for i, size in enumerate(sizes):
        with mp.get_context('spawn').Pool(1, maxtasksperchild=1) as pool:
            rows += pool.apply(big_map_rows, (building, size, max(3, poses // 2), seed + i, threads))
    return rows


def big_map_rows(building: OccupancyMap, size: int, count: int, seed: int, threads: int) -> list[dict]:
    """In a fresh process: the building tiled to size^2, bnb prepared, `count` ray-cast scans
    localized; each row carries the process's peak memory after all of them."""
    cv2.setNumThreads(threads)
    m = tiled_map(building, size, seed)
    rng = np.random.default_rng(seed + 1000)
    # the scans drawn first: the peak is then what a server holding this map reaches
    truths = sample_free_poses(m, count, rng, clearance=0.5)
    laser = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.01)
    scans = [simulate_scan(m, truth, laser, rng=rng) for truth in truths]
    loc = Localizer(m)
    loc.matcher('bnb')
    rows = []
    for truth, scan in zip(truths, scans, strict=True):
        res = loc.localize(scan, 'bnb')
        rows.append({'suite': 'tail', 'kind': 'big', 'map': f'{size}^2', 'cells': size * size, 'method': 'bnb',
                     'time_s': res.time_s, 'success': res.success, 'outcome': res.outcome.label,
                     'ok': res.pose is not None and pose_correct(res.pose, truth),
                     'expansions': getattr(res.search_stats, 'expansions', None),
                     'search_s': getattr(res.search_stats, 'search_s', None),
                     'per_level': list(getattr(res.search_stats, 'per_level', ())),
                     'top_nodes': getattr(res.search_stats, 'top_nodes', None),
                     'top_in_band': getattr(res.search_stats, 'top_in_band', None)})
    peak = round(_peak_rss_bytes() / 1e6)
    return [{**r, 'peak_mb': peak} for r in rows]


def _met(ok: bool) -> str:
    return 'met' if ok else '**not met**'


def budget_stops(rows) -> list[dict]:
    """The searches stopped at the node budget (not at the time limit)."""
    return [r for r in rows if r['outcome'] == 'search_incomplete' and (r.get('expansions') or 0) >= MAX_NODES]


def changed_lines(rows) -> list[str]:
    """The changed world's three targets."""
    median, p95 = time_quantiles(rows)
    stops = budget_stops(rows)
    explained = [r for r in stops if (r.get('score') or 0.0) >= EXPLAINED_SCORE]
    wrong = sum(r['success'] and not r['ok'] for r in rows)
    by_map = ', '.join(f'{name} {len(s)} (best score median {np.median([r.get("score") or 0 for r in s]):.2f})'
                       for name, s in sorted(group(stops, lambda r: r['map']).items()))
    named = '; '.join(f"{r['map']} score {r.get('score') or 0:.2f}" for r in explained)
    banded = [r['top_in_band'] / r['top_nodes'] for r in stops if r.get('top_in_band') and r.get('top_nodes')]
    in_band = (f'; top nodes bounded within their final band (each one an exhaustive search expands): median '
               f'{100 * np.median(banded):.0f}%' if banded else '')
    return [f'| changed world, level {CHANGE_LEVELS[-1]}: p95 ≤ {LIMITS["changed_p95_s"]:g} s | {secs(p95)} s '
            f'(median {secs(median)} s, {len(rows)} scans) | {_met(p95 <= LIMITS["changed_p95_s"])} | the p95 is the '
            f'{len(stops)} searches stopped at the node budget: {by_map or "none"}{in_band} |',
            f'| changed world: no node-budget stop on a scan the map explains (best score ≥ {EXPLAINED_SCORE:.2f}) '
            f'| {len(explained)} of {len(stops)} stops | {_met(not explained)} | '
            f'{named or "-"} |',
            f'| changed world: 0 confident-wrong | {wrong} | {_met(wrong == 0)} | |']


def logs_lines(rows) -> list[str]:
    per_log = {log: time_quantiles(s) for log, s in sorted(group(rows, lambda r: r['log']).items())}
    median, p95 = time_quantiles(rows)
    slowest = max(per_log, key=lambda k: per_log[k][1]) if per_log else '-'
    stops = len(budget_stops(rows))
    return [f'| real logs (maps ≤ 4 Mcells): median ≤ {LIMITS["logs_median_s"]:g} s, p95 ≤ '
            f'{LIMITS["logs_p95_s"]:g} s | {secs(median)} / {secs(p95)} s; per log '
            + ', '.join(f'{k} {secs(m)} / {secs(p)}' for k, (m, p) in per_log.items())
            + f' | {_met(median <= LIMITS["logs_median_s"] and p95 <= LIMITS["logs_p95_s"])} | slowest tail: '
              f'{slowest}; {stops} stopped at the node budget |']


def big_lines(rows) -> list[str]:
    out = []
    for name, s in sorted(group(rows, lambda r: r['cells']).items()):
        median, p95 = time_quantiles(s)
        stops = len(budget_stops(s))
        out.append(f'| {s[0]["map"]} ({name / 1e6:.0f} Mcells): p95 ≤ {LIMITS["big_p95_s"]:g} s | {secs(p95)} s '
                   f'(median {secs(median)} s, {len(s)} scans, {sum(r["ok"] for r in s)} right) | '
                   f'{_met(p95 <= LIMITS["big_p95_s"])} | median {int(np.median([r["expansions"] or 0 for r in s]))} '
                   f'expansions; {stops} stopped at the node budget{_coarse_share(s)} |')
    largest = max(rows, key=lambda r: r['cells'], default=None)
    if largest is not None:
        out.append(f'| peak memory on the {largest["map"]} map ≤ {LIMITS["peak_mb"]:g} MB | {largest["peak_mb"]} MB '
                   f'| {_met(largest["peak_mb"] <= LIMITS["peak_mb"])} | the whole process: bnb prepared, '
                   f'{len([r for r in rows if r["cells"] == largest["cells"]])} localizations |')
    return out


def _coarse_share(rows) -> str:
    """Where a big map's expansions go: the share at the two top levels (blocks of 2^(levels-1)
    and half that: the budget spent before the search narrows down), the time each took,
    and the top nodes within the final band (an exhaustive search expands every one of
    them: the least it needs) against those the budget reached."""
    levels = [r['per_level'] for r in rows if r.get('per_level')]
    if not levels:
        return ''
    top = float(np.median([sum(p[-2:]) / max(sum(p), 1) for p in levels]))
    each = float(np.median([r['search_s'] / r['expansions'] for r in rows if r.get('search_s') and r['expansions']]))
    line = (f'; {100 * top:.0f}% of them at the two coarsest levels (blocks of {2 ** (len(levels[0]) - 1)} and '
            f'{2 ** (len(levels[0]) - 2)} cells), {1e6 * each:.1f} µs each')
    banded = [r for r in rows if r.get('top_in_band') and r.get('top_nodes') and r.get('per_level')]
    if banded:
        share = np.median([r['top_in_band'] / r['top_nodes'] for r in banded])
        least = int(np.median([r['top_in_band'] for r in banded]))
        reached = np.median([r['per_level'][-1] / r['top_in_band'] for r in banded])
        line += (f'; {100 * share:.0f}% of the top nodes are bounded within the final band ({least} nodes: the '
                 f'least an exhaustive search expands, {secs(least * each)} s at that rate before any level '
                 f'below), the budget expanded {100 * reached:.0f}% of them')
    return line


def tail_section(rows: list[dict]) -> list[str]:
    kinds = group(rows, lambda r: r['kind'])
    lines = ['## The search\'s tail against its targets', '',
             'One localization at a time on every core (the server\'s case), bnb at its defaults. The changed world '
             f'at its heaviest level (level {CHANGE_LEVELS[-1]}: unmapped boxes, people, open wall pieces); the '
             'CARMEN logs in their held-out maps; the tiled building, each size in a fresh process whose peak '
             'memory is reported. "Where the time goes" is read from the same rows.', '',
             '| target | measured | | where the time goes |', '|---|---|---|---|']
    if kinds.get('changed'):
        lines += changed_lines(kinds['changed'])
    if kinds.get('carmen'):
        lines += logs_lines(kinds['carmen'])
    if kinds.get('big'):
        lines += big_lines(kinds['big'])
    return lines + ['', 'Success and confident-wrong against the committed reports, trial by trial: the A/B runs '
                        'of the decision records (docs/decisions), which pair each change with the same trials.', '']
