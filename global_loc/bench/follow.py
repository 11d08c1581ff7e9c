"""The `follow` suite: the server's resolution by motion on the real CARMEN logs, as
`localize --carmen LOG --follow` runs it (offline/follow.py `follow_start`). A start scan
(seeded, among those the map explains) is localized in a map (5 cm) built from every scan
of the log except those within FOLLOW_S seconds of it, before or after - so neither the
start scan nor any scan it is followed over is in the map, while the places they see are
there from the robot's other passes, as in a map made on an earlier run (the carmen
suite's time-block folds would leave out whole areas the following scans see). When
ambiguous, its hypotheses are followed over the next scans with the ODOM lines' raw
odometry for up to FOLLOW_S seconds of the log. Right: 0.2 m / 5 deg from the corrected
pose of the scan the answer is for."""
from __future__ import annotations

import os

import numpy as np

from ..core.localizer import Localizer
from ..core.transform import CORRECT_XY_M, CORRECT_YAW_DEG, Rigid2D
from ..io.carmen import GridCounts, LogGrid, read_flaser
from ..offline.follow import FollowBounds, Frame, follow_start
from .carmen import explained_fraction
from .tables import group, pct, secs

LOGS = ('intel', 'freiburg-079', 'aces')
FOLLOW_S = 20.0
MIN_EXPLAINED = 0.7       # as the carmen suite: a start scan the map explains


def right(fields: dict) -> bool:
    return 'error_xy' in fields and fields['error_xy'] < CORRECT_XY_M and fields['error_yaw_deg'] < CORRECT_YAW_DEG


def log_starts(log: str, path: str, starts: int, seed: int, follow_s: float):
    """(start index, its held-out map, the log's frames) of the seeded start scans of one log:
    each localized in the map of every scan more than follow_s from it, its pose on free space
    and its scan explained by that map."""
    records = read_flaser(path)
    grid = LogGrid(records, 0.05)
    total = grid.counts(records)
    stamps = np.array([r.timestamp for r in records])
    frames = [Frame(i, r.scan, r.odometry, r.pose) for i, r in enumerate(records)]
    done, rng = 0, np.random.default_rng(seed)
    for i in rng.permutation(len(records)):
        if done == starts:
            break
        window = grid.counts([records[j] for j in np.flatnonzero(np.abs(stamps - stamps[i]) <= follow_s)])
        m = grid.occupancy_map(GridCounts(total.hits - window.hits, total.visits - window.visits),
                               f'{log} without the {follow_s:g} s around scan {i}')
        pose = records[i].pose
        if not m.is_free_at([[pose.x, pose.y]])[0] or explained_fraction(m, records[i]) < MIN_EXPLAINED:
            continue
        done += 1
        yield int(i), m, frames


def start_row(log: str, line: dict) -> dict:
    """follow_start's line as the suite's row."""
    return {'suite': 'follow', 'log': log, 'index': line['index'], 'single_outcome': line['single']['outcome'],
            'single_ok': right(line['single']), 'followed': line['followed'], 'settled': line['settled'],
            'outcome': line['outcome'], 'ok': right(line),
            **{key: line.get(key) for key in ('distance_m', 'turn_deg', 'follow_s', 'scans', 'time_s')}}


def log_rows(log: str, path: str, starts: int, seed: int, follow_s: float) -> list[dict]:
    return [start_row(log, follow_start(Localizer(m), frames, i, FollowBounds.for_seconds(follow_s), Rigid2D(),
                                        'bnb'))
            for i, m, frames in log_starts(log, path, starts, seed, follow_s)]


def follow_rows(shared_dir: str, starts_per_log: int, seed: int, follow_s: float = FOLLOW_S) -> list[dict]:
    """One row per start scan of each shared log."""
    rows = []
    for log in LOGS:
        path = os.path.join(shared_dir, 'carmen', f'{log}-corrected.log.gz')
        if os.path.exists(path):
            rows += log_rows(log, path, starts_per_log, seed, follow_s)
    return rows


def median(values) -> float:
    return float(np.median(values)) if len(values) else float('nan')


def p95(values) -> float:
    return float(np.percentile(values, 95)) if len(values) else float('nan')


def follow_section(rows: list[dict]) -> list[str]:
    """Per log: the single scan's answers, what following the ambiguous ones settles, and its cost."""
    lines = ['## Settling by motion on real logs (follow suite)', '',
             f'Seeded start scans, each localized in the map of every scan more than {FOLLOW_S:g} s from it; an '
             'ambiguous one is followed over the next scans with the ODOM lines\' raw odometry, for up to '
             f'{FOLLOW_S:g} s of the log, exactly as the server resolves by motion (`localize --carmen LOG '
             '--follow`). "success": localized and right (0.2 m / 5° from the corrected pose of the scan the '
             'answer is for); "wrong": localized but not right; "settled": of the followed starts; "right" and '
             '"metres": of the settled ones; times per start (the single scan, plus the following).', '',
             '| log | starts | single scan: success | wrong | ambiguous | followed | settled | right | wrong '
             '| metres to settle (median) | after following: success | wrong | time median [s] | p95 [s] '
             '| followed: median [s] | p95 [s] |', '|' + '---|' * 16]
    for log, lr in sorted(group(rows, lambda r: r['log']).items()):
        n = len(lr)
        followed = [r for r in lr if r['followed']]
        settled = [r for r in followed if r['settled']]
        times = [r['time_s'] for r in lr]
        followed_times = [r['time_s'] for r in followed]
        lines.append(
            f'| {log} | {n} | {pct(sum(r["single_outcome"] == "localized" and r["single_ok"] for r in lr) / n)} '
            f'| {sum(r["single_outcome"] == "localized" and not r["single_ok"] for r in lr)} '
            f'| {sum(r["single_outcome"] == "ambiguous" for r in lr)} | {len(followed)} '
            f'| {pct(len(settled) / len(followed)) if followed else "–"} '
            f'| {pct(sum(r["ok"] for r in settled) / len(settled)) if settled else "–"} '
            f'| {sum(not r["ok"] for r in settled)} | {secs(median([r["distance_m"] for r in settled]))} '
            f'| {pct(sum(r["outcome"] == "localized" and r["ok"] for r in lr) / n)} '
            f'| {sum(r["outcome"] == "localized" and not r["ok"] for r in lr)} '
            f'| {secs(median(times))} | {secs(p95(times))} | {secs(median(followed_times))} '
            f'| {secs(p95(followed_times))} |')
    return lines + ['']
