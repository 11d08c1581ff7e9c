"""Issue 27 item 2: the band the verdict needs, A/B in one process on the same trials.

For each trial, bnb runs twice on one matcher (one precomputation), interleaved:
A = the whole keep_ratio band (band_allowance 1: the search before this change),
B = the band set from the incumbent's fit (band_allowance --allowance, 0.03: what the
runs of benchmarks/READING.md measured).
Rows (bench.worker.run_job's fields, plus the band and the A run's peaks) go to
rows.jsonl; summarize.py reads them.

Under A every distinct peak within 10% is recorded with its leaf score (cell centre, the
search's score) and its refined field score and ranking score (the verdict's), so the
refinement's rise and the band each outcome needs can be measured.

    python benchmarks/results/band/band_ab.py --suites sim,cut,prior,carmen,changed \
        --poses 6 --scans-per-log 12 --changed-poses 4 --out benchmarks/results/band
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
from global_loc.bench.changed import changed_trials
from global_loc.bench.suites import carmen_trials, cut_trials, load_maps, prior_trials, sim_trials
from global_loc.core.matchers.bnb import matcher as bnb_matcher

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


class PeakRecorder:
    """Records, for one match, the distinct peaks' leaf scores (in the order the matcher
    refines them) and each refinement's result."""

    def __init__(self, matcher):
        self.clear()
        plain_distinct = matcher.distinct

        def distinct(leaves):
            peaks = plain_distinct(leaves)
            self.searches += 1       # 2: the band did not cover, searched again with keep_ratio's
            self.peaks = [c.score for c in peaks]
            self.refined = []
            return peaks
        matcher.distinct = distinct
        plain_refine = bnb_matcher.refine

        def refine(*args):
            out = plain_refine(*args)
            self.refined.append(float(out[3]))
            return out
        bnb_matcher.refine = refine
        plain_judge = matcher.judge_exhaustive

        def judge_exhaustive(candidates):
            verdict = plain_judge(candidates)
            self.candidates = [(c.score, c.explained) for c in candidates]
            self.message = verdict.message
            return verdict
        matcher.judge_exhaustive = judge_exhaustive

    def clear(self):
        self.peaks, self.refined, self.candidates, self.message, self.searches = [], [], [], '', 0


def build(args):
    trials = []
    if {'sim', 'cut', 'prior'} & set(args.suites):
        quick_maps = load_maps(args.shared, quick=True)
        if 'cut' in args.suites:
            trials += cut_trials(quick_maps, max(1, args.poses // 5) if args.poses != 6 else 3, args.seed)
        if 'sim' in args.suites:
            trials += sim_trials(quick_maps, args.poses, args.seed)
        if 'prior' in args.suites:
            trials += prior_trials(quick_maps, args.poses, args.seed)
    else:
        quick_maps = {}
    maps = dict(quick_maps)
    if 'changed' in args.suites:
        full = load_maps(args.shared, quick=False)
        maps.update(full)
        trials += changed_trials(full, args.changed_poses, args.seed)
    if 'carmen' in args.suites:
        carmen, carmen_maps, _ = carmen_trials(args.shared, args.scans_per_log, args.seed)
        maps.update(carmen_maps)
        trials += carmen
    return trials, maps


def trial_matcher(i, trial):
    """The bnb matcher of the trial's map in this process (shared with settle/settle_ab.py);
    the first time, a localization of the trial builds it (and compiles numba's kernels)."""
    if trial.map_name not in worker._LOCALIZERS:
        worker.run_job((i, trial, 'bnb'))
    return worker._LOCALIZERS[trial.map_name].matcher('bnb')


def add_trial_arguments(p: argparse.ArgumentParser, suites: str, seed: int, threads: int) -> None:
    """The options `build` reads, and the search threads (shared with settle/settle_ab.py)."""
    p.add_argument('--suites', default=suites)
    p.add_argument('--poses', type=int, default=6)
    p.add_argument('--changed-poses', type=int, default=4)
    p.add_argument('--scans-per-log', type=int, default=12)
    p.add_argument('--seed', type=int, default=seed)
    p.add_argument('--threads', type=int, default=threads, help='search threads (cv2.setNumThreads)')
    p.add_argument('--shared', default=os.path.join(REPO, '..', 'shared', 'data'))


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    add_trial_arguments(p, 'sim,cut,prior,carmen,changed', 0, 1)
    p.add_argument('--allowance', type=float, default=0.03, help="B's band_allowance")
    p.add_argument('--out', default=os.path.dirname(os.path.abspath(__file__)))
    args = p.parse_args(argv)
    args.suites = args.suites.split(',')
    trials, maps = build(args)
    print(f'{len(trials)} trials', file=sys.stderr)
    worker.worker_init(maps, args.threads)
    cv2.setNumThreads(args.threads)
    recorders = {}
    t0 = time.time()
    with open(os.path.join(args.out, 'rows.jsonl'), 'w') as out:
        for i, trial in enumerate(trials):
            m = trial_matcher(i, trial)
            if trial.map_name not in recorders:
                recorders[trial.map_name] = (PeakRecorder(m), m.options)
            rec, default = recorders[trial.map_name]
            b_opts = replace(default, band_allowance=args.allowance)
            for variant, opts in (('A', replace(default, band_allowance=1.0)), ('B', b_opts)):
                m.options = opts
                rec.clear()
                row = worker.run_job((i, trial, 'bnb'))
                row.update(variant=variant, band_allowance=opts.band_allowance, verdict_message=rec.message,
                           searches=rec.searches,
                           peak_leaf=rec.peaks, peak_fit=rec.refined, candidates=rec.candidates)
                out.write(json.dumps(row) + '\n')
            m.options = default
            if i % 20 == 0:
                print(f'{i}/{len(trials)} {time.time() - t0:.0f} s', file=sys.stderr, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
