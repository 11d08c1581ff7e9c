"""The band the verdict needs, read from options_ab's rows of an arm with the whole
keep_ratio band (band_allowance 1.0): how much the refinement raises a peak over its leaf,
the allowance each trial's outcome needs, and the outcomes the hypotheses would get if the
search had kept only the band of a given allowance (replayed through the verdict).

    python -m benchmarks.experiments.options_ab --a band_allowance=1.0 --b band_allowance=0.03 --out out/band
    python -m benchmarks.experiments.band_replay out/band/rows.jsonl
"""
from __future__ import annotations

import json
import math
import sys

import numpy as np

from global_loc.core.matchers.base import Candidate
from global_loc.core.matchers.bnb.options import BranchAndBoundOptions
from global_loc.core.matchers.bnb.verdict import judge, searched_keep
from global_loc.core.transform import Rigid2D

OPT = BranchAndBoundOptions()


def need_at(fit: float) -> float:
    explained = min(max((fit - 0.3) / 0.3, 0.0), 1.0)
    return OPT.min_confidence * (1 - OPT.keep_ratio) / explained if explained > 0 else math.inf


def needed_allowance(row: dict):
    """The allowance this A row's outcome needs: over the peaks that can change it (the
    ranking's best, and every place within the lead a confident answer needs of it, in
    field or ranking score), how far behind the best leaf their leaves lie, less the lead
    needed at the best leaf's fit. None without peaks or at a fit where the band is the
    whole keep_ratio band anyway."""
    leaf, fit, cands = row['peak_leaf'], row['peak_fit'], row['candidates']
    if not leaf or len(fit) != len(leaf) or not cands:
        return None
    rank_of = {f: r for r, f in cands}
    rank = [rank_of.get(f) for f in fit]
    r0, f0 = cands[0]
    need = need_at(f0)
    if not math.isfinite(need):
        return None
    l_max = max(leaf)
    matter = [i for i in range(len(leaf)) if fit[i] == f0 or fit[i] >= (1 - need) * f0
              or (rank[i] is not None and rank[i] >= (1 - need) * r0)]
    gap = max(1 - leaf[i] / l_max for i in matter)
    return gap - need_at(l_max), len(matter) - 1


def replayed_outcomes(row: dict, allowance: float):
    """The verdict an A row's hypotheses get under the whole keep_ratio band, and the one
    they would get from the band with this allowance (the places whose leaf lies within
    it: the search returns exactly those, its leaves an upper set of the whole band's)."""
    leaf_of = dict(zip(row['peak_fit'], row['peak_leaf'], strict=True))
    cands = [Candidate(Rigid2D(float(i), 0.0, 0.0), rank, explained=fit, see_through=1 - rank / fit if fit else 0.0)
             for i, (rank, fit) in enumerate(row['candidates'])]
    best_leaf = max(row['peak_leaf'])
    keep = searched_keep(best_leaf, OPT.keep_ratio, OPT.min_confidence, allowance)
    seen = [c for c in cands if leaf_of[c.explained] >= keep * best_leaf]
    return (judge(cands, BranchAndBoundOptions(band_allowance=1.0)).outcome,
            judge(seen, BranchAndBoundOptions(band_allowance=allowance)).outcome)


def pct(values, q):
    return float(np.percentile(values, q)) if values else float('nan')


def main(paths) -> int:
    rows = [json.loads(line) for p in paths for line in open(p) if line.strip()]
    # the refinement's rise, and each trial's needed allowance (A rows: the whole band)
    a_rows = [r for r in rows if r['arm'] == 'A']
    rise = [f - lf for r in a_rows for lf, f in zip(r['peak_leaf'], r['peak_fit'], strict=False)]
    rel = [f / lf - 1 for r in a_rows for lf, f in zip(r['peak_leaf'], r['peak_fit'], strict=False) if lf > 0]
    print(f'refined - leaf score over {len(rise)} peaks: min {min(rise):+.4f}, p5 {pct(rise, 5):+.4f}, median '
          f'{pct(rise, 50):+.4f}, p95 {pct(rise, 95):+.4f}, p99 {pct(rise, 99):+.4f}, max {max(rise):+.4f}; relative '
          f'max {max(rel):+.4f}')
    # a peak's gap to the best, in leaf score less in refined score: what refinement closes
    closing = []
    for r in a_rows:
        lf, f = r['peak_leaf'], r['peak_fit']
        if len(lf) > 1 and len(f) == len(lf):
            closing += [(1 - lf[i] / max(lf)) - (1 - f[i] / max(f)) for i in range(len(lf))]
    if closing:
        print(f'leaf gap - refined gap over {len(closing)} peaks: p50 {pct(closing, 50):+.4f}, p95 '
              f'{pct(closing, 95):+.4f}, p99 {pct(closing, 99):+.4f}, max {max(closing):+.4f}')
    needed = [(needed_allowance(r), r) for r in a_rows]
    needed = [(n[0], n[1], r) for n, r in needed if n is not None]
    vals = [n for n, _, _ in needed]
    print(f'allowance each outcome needs, {len(vals)} trials with peaks: median {pct(vals, 50):+.4f}, p95 '
          f'{pct(vals, 95):+.4f}, max {max(vals):+.4f}; with a rival that can change the outcome: '
          f'{sum(k > 0 for _, k, _ in needed)}')
    for n, k, r in sorted(needed, key=lambda t: -t[0])[:6]:
        print(f'  needs {n:+.4f}: {r["suite"]} {r["map"]} trial {r["trial"]} {r["outcome"]} rivals {k} '
              f'leaf {[round(x, 3) for x in r["peak_leaf"][:4]]} fit {[round(x, 3) for x in r["peak_fit"][:4]]}')
    replayable = [r for r in a_rows if r['candidates'] and len(r['peak_fit']) == len(r['peak_leaf'])]
    for allowance in (0.0, 0.01, 0.02, 0.03, 0.04):
        flips = [(r['suite'], r['map'], r['trial'], *(o.label for o in replayed_outcomes(r, allowance)), r['ok'])
                 for r in replayable]
        flips = [f for f in flips if f[3] != f[4]]
        print(f'replayed at band_allowance {allowance}: {len(flips)} of {len(replayable)} outcomes change {flips[:4]}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
