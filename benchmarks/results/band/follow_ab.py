"""The follow suite (resolution by motion on the CARMEN logs, bench/follow.py) A/B in one
process: each start localized and followed twice on one Localizer - A with the whole
keep_ratio band (band_allowance 1), B with the band the verdict needs (--allowance) -
rows to rows.jsonl with the variant.

    python benchmarks/results/band/follow_ab.py --starts 15 --out benchmarks/results/band/follow
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import replace

import numpy as np

from global_loc.bench.carmen import GridCounts, LogGrid, explained_fraction, read_flaser
from global_loc.bench.follow import FOLLOW_S, LOGS, MIN_EXPLAINED, right
from global_loc.core.localizer import Localizer
from global_loc.core.transform import Rigid2D
from global_loc.offline_follow import Frame, follow_start

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


def log_rows(log: str, path: str, starts: int, seed: int, allowance: float, out) -> None:
    """bench.follow.log_rows' starts, each followed with A and B."""
    records = read_flaser(path)
    grid = LogGrid(records, 0.05)
    total = grid.counts(records)
    stamps = np.array([r.timestamp for r in records])
    frames = [Frame(i, r.scan, r.odometry, r.pose) for i, r in enumerate(records)]
    done, rng = 0, np.random.default_rng(seed)
    for i in rng.permutation(len(records)):
        if done == starts:
            break
        window = grid.counts([records[j] for j in np.flatnonzero(np.abs(stamps - stamps[i]) <= FOLLOW_S)])
        m = grid.occupancy_map(GridCounts(total.hits - window.hits, total.visits - window.visits), f'{log} {i}')
        pose = records[i].pose
        if not m.is_free_at([[pose.x, pose.y]])[0] or explained_fraction(m, records[i]) < MIN_EXPLAINED:
            continue
        done += 1
        loc = Localizer(m)
        matcher = loc.matcher('bnb')
        default = matcher.options
        for variant, opts in (('A', replace(default, band_allowance=1.0)), ('B', replace(default,
                                                                                          band_allowance=allowance))):
            matcher.options = opts
            line = follow_start(loc, frames, int(i), FOLLOW_S, Rigid2D(), 'bnb')
            out.write(json.dumps({'variant': variant, 'log': log, 'index': line['index'],
                                  'single_outcome': line['single']['outcome'], 'single_ok': right(line['single']),
                                  'followed': line['followed'], 'settled': line['settled'],
                                  'outcome': line['outcome'], 'ok': right(line),
                                  **{k: line.get(k) for k in ('distance_m', 'turn_deg', 'scans', 'time_s')}}) + '\n')
            out.flush()


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument('--starts', type=int, default=15, help='starts per log')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--allowance', type=float, default=0.03, help="B's band_allowance")
    p.add_argument('--shared', default=os.path.join(REPO, '..', 'shared', 'data'))
    p.add_argument('--out', default=os.path.join(os.path.dirname(os.path.abspath(__file__)), 'follow'))
    args = p.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, 'rows.jsonl'), 'w') as out:
        for log in LOGS:
            path = os.path.join(args.shared, 'carmen', f'{log}-corrected.log.gz')
            if os.path.exists(path):
                log_rows(log, path, args.starts, args.seed, args.allowance, out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
