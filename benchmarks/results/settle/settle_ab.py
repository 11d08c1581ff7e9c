"""Issue 27: the settled end of the search, A/B in one process on the same trials.

For each trial, bnb runs twice on one matcher (one precomputation), interleaved:
A = the whole band (settle_slack 1, the default: never ends early), B = --slack (0.05:
ends once no place it has not scored can make the answer confident).
Rows (bench.worker.run_job's fields plus the arm) go to rows.jsonl; summarize.py reads them.

    python benchmarks/results/settle/settle_ab.py --suites changed --changed-poses 4 --out <dir>
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace

import cv2

from global_loc.bench import worker

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'band'))
from band_ab import add_trial_arguments, build, trial_matcher  # noqa: E402  (the band A/B's trials: the same suites and counts)


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    add_trial_arguments(p, 'changed', 2015, 2)
    p.add_argument('--slack', type=float, default=0.05, help="B's settle_slack")
    p.add_argument('--out', required=True)
    args = p.parse_args(argv)
    args.suites = args.suites.split(',')
    os.makedirs(args.out, exist_ok=True)
    trials, maps = build(args)
    print(f'{len(trials)} trials', file=sys.stderr)
    worker.worker_init(maps, args.threads)
    cv2.setNumThreads(args.threads)
    t0 = time.time()
    with open(os.path.join(args.out, 'rows.jsonl'), 'w') as out:
        for i, trial in enumerate(trials):
            m = trial_matcher(i, trial)
            default = m.options
            arms = (('A', replace(default, settle_slack=1.0)), ('B', replace(default, settle_slack=args.slack)))
            for arm, opts in arms:
                m.options = opts
                row = worker.run_job((i, trial, 'bnb'))
                row.update(arm=arm, settle_slack=opts.settle_slack)
                out.write(json.dumps(row) + '\n')
                out.flush()
            m.options = default
            if i % 20 == 0:
                print(f'{i}/{len(trials)} {time.time() - t0:.0f} s', file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
