"""Tables for settle_ab.py's rows: per suite (and change level), A (never ends early)
against B (the settled end), and every trial whose outcome, `ok` or `success` changed.

    python benchmarks/results/settle/summarize.py benchmarks/results/settle/<run>/rows.jsonl
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np


def key(r):
    if r['suite'] == 'changed':
        return f"changed level {r['change']}"
    if r['suite'] == 'carmen':
        return f"carmen {r['log']}"
    return r['suite']


def fig(rows):
    t = np.array([r['time_s'] for r in rows if r['time_s'] == r['time_s']])     # (NaN: the scan was refused)
    return (f"{sum(r['ok'] for r in rows)} / {sum(r['success'] for r in rows)} / "
            f"{sum(r['success'] and not r['ok'] for r in rows)}",
            f'{np.median(t):.3f} / {np.percentile(t, 95):.2f}',
            f"{int(np.median([r.get('expansions', 0) for r in rows]))}",
            sum(r['outcome'] == 'search_incomplete' for r in rows))


def main(path):
    rows = [json.loads(line) for line in open(path)]
    pairs = defaultdict(dict)
    for r in rows:
        pairs[(r['trial'])][r['arm']] = r
    groups = defaultdict(list)
    for p in pairs.values():
        if 'A' in p and 'B' in p:
            groups[key(p['A'])].append(p)
    print('| set | n | right / success / confident-wrong, A -> B | median / p95 s, A -> B | p95 ratio B/A '
          '| median expansions, A -> B | budget stops A -> B | B ended settled | outcome changed |')
    print('|---|---|---|---|---|---|---|---|---|')
    changed = []
    for name in sorted(groups):
        ps = groups[name]
        a, b = [p['A'] for p in ps], [p['B'] for p in ps]
        fa, fb = fig(a), fig(b)
        ta, tb = (np.nanpercentile([r['time_s'] for r in arm], 95) for arm in (a, b))
        diff = [p for p in ps if (p['A']['outcome'], p['A']['ok'], p['A']['success'])
                != (p['B']['outcome'], p['B']['ok'], p['B']['success'])]
        changed += [(name, p) for p in diff]
        print(f'| {name} | {len(ps)} | {fa[0]} -> {fb[0]} | {fa[1]} -> {fb[1]} | {tb / ta:.2f} | {fa[2]} -> {fb[2]} '
              f"| {fa[3]} -> {fb[3]} | {sum(bool(r.get('settled')) for r in b)} | {len(diff)} |")
    print()
    for name, p in changed:
        a, b = p['A'], p['B']
        print(f"- {name} trial {a['trial']} ({a['map']}): {a['outcome']} ok={a['ok']} score {a.get('score')} "
              f"({a.get('expansions')} exp, {a['time_s']:.2f} s) -> {b['outcome']} ok={b['ok']} score {b.get('score')} "
              f"({b.get('expansions')} exp, {b['time_s']:.2f} s)")


if __name__ == '__main__':
    main(sys.argv[1])
