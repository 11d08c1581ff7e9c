"""bnb with two sets of options (A and B) on the benchmark's trials, in one process on one
matcher per map and arm (each built with its arm's options), the two arms interleaved trial by trial so the
machine's drift falls on both. Rows: bench.worker.run_job's fields plus the arm, its
options, and each match's peaks (leaf scores, refined fits, ranked candidates) read through
`BranchAndBoundMatcher.on_peaks`. `--summarize` reads them: per suite (and change level or
log) right / success / confident-wrong, time and expansions, A against B, and every trial
whose outcome changed.

    python -m benchmarks.experiments.options_ab --suites sim,cut,prior,carmen,changed \\
        --a band_allowance=1.0 --b band_allowance=0.03 --out out/band
    python -m benchmarks.experiments.options_ab --summarize out/band/rows.jsonl
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from dataclasses import fields, replace

import cv2
import numpy as np

from global_loc.bench import worker
from global_loc.bench.changed import changed_trials
from global_loc.bench.suites import carmen_trials, cut_trials, load_maps, prior_trials, sim_trials
from global_loc.bench.unmapped import unmapped_trials
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.matchers import BranchAndBoundOptions

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def parse_options(pairs: list[str]) -> dict:
    """['band_allowance=0.03', ...] -> {'band_allowance': 0.03}; an unknown name is an error."""
    known = {f.name: f.type for f in fields(BranchAndBoundOptions)}
    out = {}
    for pair in pairs:
        name, _, value = pair.partition('=')
        if name not in known:
            raise SystemExit(f'{name}: not a BranchAndBoundOptions field ({", ".join(sorted(known))})')
        out[name] = type(getattr(BranchAndBoundOptions(), name))(value)
    return out


def build(args) -> tuple[list, dict]:
    """The trials of the asked suites (seeded as the benchmark's) and the maps they need."""
    trials, maps = [], {}
    if {'sim', 'cut', 'prior'} & set(args.suites):
        maps.update(load_maps(args.shared, quick=True))
        if 'cut' in args.suites:
            trials += cut_trials(maps, max(1, args.poses // 5), args.seed)
        if 'sim' in args.suites:
            trials += sim_trials(maps, args.poses, args.seed)
        if 'prior' in args.suites:
            trials += prior_trials(maps, args.poses, args.seed)
    if 'changed' in args.suites:
        full = load_maps(args.shared, quick=False)
        maps.update(full)
        trials += changed_trials(full, args.changed_poses, args.seed)
    if 'unmapped' in args.suites:
        trials += unmapped_trials(load_maps(args.shared, quick=False), args.changed_poses, args.seed)
    if 'carmen' in args.suites:
        carmen, carmen_maps, _ = carmen_trials(args.shared, args.scans_per_log, args.seed)
        maps.update(carmen_maps)
        trials += carmen
    return trials, maps


class PeakRecord:
    """The peaks of a localization's first match (the scan's own search), as the matcher's
    on_peaks hook hands them over; `searches` counts every match of the localization (the
    mirror check and a rival search are matches too)."""

    def __init__(self):
        self.leaf, self.fit, self.candidates, self.searches = [], [], [], 0

    def __call__(self, leaf, fit, candidates):
        self.searches += 1
        if self.searches == 1:
            self.leaf, self.fit = leaf, fit
            self.candidates = [(c.score, c.explained) for c in candidates]


class ArmLocalizers:
    """One Localizer per (map, arm), built with the arm's options: an option that shapes the
    precomputation (bnb.unknown_credit adds the optimistic planes) is then compared as a
    server would run it, not swapped into a matcher built without it. A trial with a map of
    its own (the unmapped suite) gets its two for it alone."""

    def __init__(self, arms):
        self.arms = dict(arms)
        self.built, self.own = {}, None

    def __call__(self, trial, arm: str):
        if trial.own_map is not None:
            if self.own is None or self.own[0] is not trial.own_map:
                self.own = (trial.own_map, {})
            cache, key, source = self.own[1], arm, trial.own_map
        else:
            cache, key, source = self.built, (trial.map_name, arm), worker._MAPS[trial.map_name]
        if key not in cache:
            options = replace(BranchAndBoundOptions(), **self.arms[arm])
            cache[key] = Localizer(source, LocalizerConfig(bnb=options))
        return cache[key]


def run(args) -> int:
    arms = (('A', parse_options(args.a)), ('B', parse_options(args.b)))
    trials, maps = build(args)
    print(f'{len(trials)} trials, A {arms[0][1]}, B {arms[1][1]}', file=sys.stderr)
    worker.worker_init(maps, args.threads)
    cv2.setNumThreads(args.threads)
    os.makedirs(args.out, exist_ok=True)
    localizers, current = ArmLocalizers(arms), [None]
    worker.localizer_of = lambda trial: current[0]     # run_job localizes on the arm's Localizer
    t0 = time.time()
    with open(os.path.join(args.out, 'rows.jsonl'), 'w') as out:
        for i, trial in enumerate(trials):
            for arm, changes in arms:
                current[0] = localizers(trial, arm)
                matcher = current[0].matcher('bnb')
                matcher.on_peaks = PeakRecord()
                row = worker.run_job((i, trial, 'bnb'))
                peaks = matcher.on_peaks
                row.update(arm=arm, options=changes, searches=peaks.searches, peak_leaf=peaks.leaf,
                           peak_fit=peaks.fit, candidates=peaks.candidates)
                out.write(json.dumps(row) + '\n')
                matcher.on_peaks = None
            if i % 20 == 0:
                print(f'{i}/{len(trials)} {time.time() - t0:.0f} s', file=sys.stderr, flush=True)
    return 0


def group_name(r: dict) -> str:
    if r['suite'] == 'changed':
        return f"changed level {r['change']}"
    if r['suite'] == 'unmapped':
        return f"unmapped {r['cut']} {r['unmapped_m']:g} m"
    return f"carmen {r['log']}" if r['suite'] == 'carmen' else r['suite']


def figures(rows: list[dict]) -> tuple[str, str, str, int]:
    t = np.array([r['time_s'] for r in rows if r['time_s'] == r['time_s']])     # NaN: the scan was refused
    return (f"{sum(r['ok'] for r in rows)} / {sum(r['success'] for r in rows)} / "
            f"{sum(r['success'] and not r['ok'] for r in rows)}",
            f'{np.median(t):.3f} / {np.percentile(t, 95):.2f}' if len(t) else '–',
            f"{int(np.median([r.get('expansions', 0) for r in rows]))}",
            sum(r['outcome'] == 'search_incomplete' for r in rows))


def arm_pairs(paths: list[str], key) -> dict:
    """The rows of A/B runs, paired: key(path, row) -> {'A': row, 'B': row}."""
    pairs = defaultdict(dict)
    for path in paths:
        for line in open(path):
            if line.strip():
                r = json.loads(line)
                pairs[key(path, r)][r['arm']] = r
    return pairs


def summarize(paths: list[str]) -> list[str]:
    """The A/B table and the changed trials, as markdown lines."""
    pairs = arm_pairs(paths, lambda path, r: (path, r['trial']))
    groups = defaultdict(list)
    for p in pairs.values():
        if 'A' in p and 'B' in p:
            groups[group_name(p['A'])].append(p)
    lines = ['| set | n | right / success / confident-wrong, A -> B | median / p95 s, A -> B '
             '| median expansions, A -> B | node-budget stops, A -> B | outcome changed |', '|---' * 7 + '|']
    changed = []
    for name in sorted(groups):
        ps = groups[name]
        fa, fb = figures([p['A'] for p in ps]), figures([p['B'] for p in ps])
        diff = [p for p in ps if any(p['A'].get(k) != p['B'].get(k) for k in ('outcome', 'ok', 'success'))]
        changed += [(name, p) for p in diff]
        lines.append(f'| {name} | {len(ps)} | {fa[0]} -> {fb[0]} | {fa[1]} -> {fb[1]} | {fa[2]} -> {fb[2]} '
                     f'| {fa[3]} -> {fb[3]} | {len(diff)} |')
    lines.append('')
    for name, p in changed:
        a, b = p['A'], p['B']
        lines.append(f"- {name} trial {a['trial']} ({a['map']}): {a['outcome']} ok={a['ok']} score {a.get('score')} "
                     f"-> {b['outcome']} ok={b['ok']} score {b.get('score')}")
    return lines


def arm_arguments(description: str, out: str) -> argparse.ArgumentParser:
    """The arguments every A/B experiment takes: the two arms, the seed, the data and the output."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument('--summarize', nargs='+', metavar='ROWS', help='read these rows.jsonl files; run nothing')
    p.add_argument('--a', nargs='*', default=[], metavar='NAME=VALUE', help="arm A's options (default: bnb's)")
    p.add_argument('--b', nargs='*', default=[], metavar='NAME=VALUE', help="arm B's options")
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--shared', default=os.path.join(REPO, '..', 'shared', 'data'))
    p.add_argument('--out', default=os.path.join(REPO, 'out', out))
    return p


def experiment_main(p: argparse.ArgumentParser, argv, run_fn, summarize_fn) -> int:
    """Run the experiment, or with --summarize read rows it wrote."""
    args = p.parse_args(argv)
    if args.summarize:
        print('\n'.join(summarize_fn(args.summarize)))
        return 0
    return run_fn(args)


def main(argv=None) -> int:
    p = arm_arguments(__doc__.split('\n\n')[0], 'options_ab')
    p.add_argument('--suites', default='sim,cut,prior,carmen,changed', type=lambda s: s.split(','))
    p.add_argument('--poses', type=int, default=6)
    p.add_argument('--changed-poses', type=int, default=4, help='poses per map of the changed and unmapped suites')
    p.add_argument('--scans-per-log', type=int, default=12)
    p.add_argument('--threads', type=int, default=1, help='search threads (cv2.setNumThreads)')
    return experiment_main(p, argv, run, summarize)


if __name__ == '__main__':
    sys.exit(main())
