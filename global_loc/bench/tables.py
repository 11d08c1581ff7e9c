"""The benchmark's figures from its rows: success shares, median and p95 time; the
number formats of the report's tables."""
from __future__ import annotations

import math
import os
from collections import defaultdict

import numpy as np

BASELINE = 'template_ccoeff'


def stats(rows: list[dict]) -> dict:
    times = np.array([r['time_s'] for r in rows if math.isfinite(r.get('time_s', float('nan')))])
    n = len(rows)
    return {'n': n,
            'ok': sum(r['ok'] for r in rows) / n if n else float('nan'),
            'ok_loose': sum(r['ok_loose'] for r in rows) / n if n else float('nan'),
            'top4': sum(r.get('top4_ok', False) for r in rows) / n if n else float('nan'),
            'marked_wrong': sum(r['success'] and not r['ok'] for r in rows) / n if n else float('nan'),
            'marked': sum(r['success'] for r in rows) / n if n else float('nan'),
            'median': float(np.median(times)) if len(times) else float('nan'),
            'p95': float(np.percentile(times, 95)) if len(times) else float('nan')}


def group(rows, key):
    out = defaultdict(list)
    for r in rows:
        out[key(r)].append(r)
    return out


def pct(v):
    return '–' if not math.isfinite(v) else f'{100 * v:.0f}%'


def secs(v):
    return '–' if not math.isfinite(v) else (f'{v:.3f}' if v < 1 else f'{v:.2f}')


def save_figure(fig, out: str, name: str, dpi: int = 90) -> None:
    """Lay out, write `out`/`name` and free the figure (pyplot keeps every open one)."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    fig.savefig(os.path.join(out, name), dpi=dpi)
    plt.close(fig)
