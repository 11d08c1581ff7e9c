"""The follow suite (resolution by motion on the CARMEN logs, global_loc/bench/follow.py)
with two sets of bnb options (A and B): each start localized and followed twice on one
Localizer, the arms interleaved; rows (the suite's fields plus the arm) to rows.jsonl, which
`--summarize` reads.

    python -m benchmarks.experiments.follow_ab --a band_allowance=1.0 --b band_allowance=0.03 --out out/follow_ab
"""
from __future__ import annotations

import json
import os
import sys
from dataclasses import replace

from global_loc.bench.follow import FOLLOW_S, LOGS, log_starts, start_row
from global_loc.core.localizer import Localizer
from global_loc.core.transform import Rigid2D
from global_loc.offline.follow import FollowBounds, follow_start

from .options_ab import arm_arguments, arm_pairs, experiment_main, parse_options


def run(args) -> int:
    arms = (('A', parse_options(args.a)), ('B', parse_options(args.b)))
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, 'rows.jsonl'), 'w') as out:
        for log in LOGS:
            path = os.path.join(args.shared, 'carmen', f'{log}-corrected.log.gz')
            if not os.path.exists(path):
                continue
            for i, m, frames in log_starts(log, path, args.starts, args.seed, FOLLOW_S):
                loc = Localizer(m)
                matcher = loc.matcher('bnb')
                default = matcher.options
                for arm, changes in arms:
                    matcher.options = replace(default, **changes)
                    line = follow_start(loc, frames, i, FollowBounds.for_seconds(FOLLOW_S), Rigid2D(), 'bnb')
                    out.write(json.dumps({**start_row(log, line), 'arm': arm, 'options': changes}) + '\n')
                    out.flush()
                matcher.options = default
    return 0


def summarize(paths: list[str]) -> list[str]:
    """Per log and arm: right after following, confident-wrong, settled; and the starts whose end changed."""
    pairs = arm_pairs(paths, lambda path, r: (r['log'], r['index']))
    lines = ['| log | arm | starts | right | confident-wrong | followed | settled |', '|---' * 7 + '|']
    for log in sorted({k[0] for k in pairs}):
        for arm in 'AB':
            rr = [p[arm] for k, p in pairs.items() if k[0] == log and arm in p]
            wrong = sum(r['outcome'] == 'localized' and not r['ok'] for r in rr)
            lines.append(f"| {log} | {arm} | {len(rr)} | {sum(r['ok'] for r in rr)} | {wrong} "
                         f"| {sum(bool(r['followed']) for r in rr)} | {sum(bool(r['settled']) for r in rr)} |")
    changed = [(k, p) for k, p in sorted(pairs.items()) if 'A' in p and 'B' in p
               and (p['A']['outcome'], p['A']['ok']) != (p['B']['outcome'], p['B']['ok'])]
    return lines + [''] + [f"- {log} start {index}: {p['A']['outcome']} ok={p['A']['ok']} -> {p['B']['outcome']} "
                           f"ok={p['B']['ok']}" for (log, index), p in changed]


def main(argv=None) -> int:
    p = arm_arguments(__doc__.split('\n\n')[0], 'follow_ab')
    p.add_argument('--starts', type=int, default=15, help='starts per log')
    return experiment_main(p, argv, run, summarize)


if __name__ == '__main__':
    sys.exit(main())
