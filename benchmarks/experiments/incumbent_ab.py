"""Does `features`' proposal, as bnb's first incumbent, make a whole localization faster than
bnb alone? (docs/decisions/0021.)

A: bnb alone. B: the feature proposal, its best fit on the map (bnb's `fit_at`, less
REFINED_GAIN by default, `--gain`: a leaf of that place may score that much below its refined fit), then bnb
seeded with it (MatchOptions.incumbent: nodes below that fit's band are pruned from the
start). Both on the same scans, one after the other in one process: ray-cast 270 deg / 20 m
scans on the benchmark's maps and held-out CARMEN scans. Prints per map the medians of A and
of B (proposal + fit + seeded search) and how often their outcomes and poses agree.

    python -m benchmarks.experiments.incumbent_ab --poses 8 --scans-per-log 10
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from global_loc.bench.suites import carmen_trials, load_maps
from global_loc.core.localizer import Localizer
from global_loc.core.matchers.base import MatchOptions
from global_loc.core.matchers.bnb.verdict import REFINED_GAIN
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import pose_correct
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan

# ray-cast 270 deg / 20 m scans with 1 cm noise, no dropouts
LASER = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0)


def seeded(loc: Localizer, points, gain: float) -> tuple:
    """B: (result, seconds, the incumbent used) - the proposal, its fit less `gain`, bnb seeded with it."""
    t0 = time.perf_counter()
    proposals = loc.matcher('features').match(points, MatchOptions()).candidates
    incumbent = 0.0
    if proposals:
        fit = loc.matcher('bnb').fit_at(points, proposals[0].laser_pose)[0]
        incumbent = max(fit - gain, 0.0)
    result = loc.localize_points(points, 'bnb', t0=t0, incumbent=incumbent)
    return result, time.perf_counter() - t0, incumbent


def one_scan(loc: Localizer, points, truth, gain: float) -> dict:
    t0 = time.perf_counter()
    alone = loc.localize_points(points, 'bnb')
    alone_s = time.perf_counter() - t0
    with_proposal, seeded_s, incumbent = seeded(loc, points, gain)
    return {'a_s': alone_s, 'b_s': seeded_s, 'incumbent': incumbent,
            'a_ok': alone.success and pose_correct(alone.pose, truth),
            'b_ok': with_proposal.success and pose_correct(with_proposal.pose, truth),
            'same': alone.outcome == with_proposal.outcome and (alone.pose is None or with_proposal.pose is None or
                                                                 pose_correct(alone.pose, with_proposal.pose)),
            'a_nodes': alone.search_stats.expansions, 'b_nodes': with_proposal.search_stats.expansions}


def problems(args) -> dict:
    """Map name -> (map, [(points, truth)]): ray-cast scans on the maps, held-out real scans."""
    out = {}
    for i, (name, m) in enumerate(load_maps(args.shared, False).items()):
        rng = np.random.default_rng(args.seed + i)
        scans = []
        for pose in sample_free_poses(m, args.poses, rng, clearance=0.5):
            scans.append((scan_to_points(simulate_scan(m, pose, LASER, rng=rng)), pose))
        out[name] = (m, scans)
    trials, maps, _ = carmen_trials(args.shared, args.scans_per_log, args.seed)
    for t in trials:
        out.setdefault(t.map_name, (maps[t.map_name], []))[1].append((scan_to_points(t.scan), t.truth))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--shared', default='../shared/data')
    parser.add_argument('--poses', type=int, default=8)
    parser.add_argument('--scans-per-log', type=int, default=10)
    parser.add_argument('--seed', type=int, default=2015)
    parser.add_argument('--gain', type=float, default=REFINED_GAIN,
                        help='the incumbent is the proposal\'s refined fit less this (0: the fit itself)')
    parser.add_argument('--out', default='')
    args = parser.parse_args(argv)
    rows = []
    for name, (m, scans) in problems(args).items():
        loc = Localizer(m)
        loc.matcher('bnb'), loc.matcher('features')        # built before any timing
        rr = [{'map': name, **one_scan(loc, points, truth, args.gain)} for points, truth in scans]
        rows += rr
        a, b = np.median([r['a_s'] for r in rr]), np.median([r['b_s'] for r in rr])
        print(f'{name}: n {len(rr)} bnb {a:.3f} s, proposal + seeded bnb {b:.3f} s ({b / a:.2f}x); nodes '
              f'{np.median([r["a_nodes"] for r in rr]):.0f} -> {np.median([r["b_nodes"] for r in rr]):.0f}; right '
              f'{sum(r["a_ok"] for r in rr)} -> {sum(r["b_ok"] for r in rr)}; same answer {sum(r["same"] for r in rr)}',
              flush=True)
    if args.out:
        with open(args.out, 'w') as f:
            f.writelines(json.dumps(r) + '\n' for r in rows)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
