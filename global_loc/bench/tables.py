"""The benchmark's figures from its rows: success shares, median and p95 time; the
number formats of the report's tables."""
from __future__ import annotations

import gzip
import io
import json
import math
import os
from collections import defaultdict

import numpy as np

BASELINE = 'template_ccoeff'
ROWS = 'rows.jsonl.gz'      # a run's raw rows in its output folder: JSON lines, gzip (a tenth of the size)


def write_rows(folder: str, rows: list[dict]) -> None:
    """The rows as JSON lines, compressed with a fixed gzip header (the same rows, the same bytes)."""
    with open(os.path.join(folder, ROWS), 'wb') as raw, gzip.GzipFile(fileobj=raw, mode='wb', mtime=0) as packed, \
            io.TextIOWrapper(packed, encoding='utf-8') as f:
        for row in rows:
            f.write(json.dumps(row) + '\n')


def read_rows(folder: str) -> list[dict]:
    """The rows write_rows wrote in `folder`."""
    with gzip.open(os.path.join(folder, ROWS), 'rt', encoding='utf-8') as f:
        return [json.loads(line) for line in f if line.strip()]


def time_quantiles(rows: list[dict]) -> tuple[float, float]:
    """The rows' median and p95 time (NaN for none); rows without a finite time are left out."""
    times = np.array([r['time_s'] for r in rows if math.isfinite(r.get('time_s', float('nan')))])
    return (float(np.median(times)), float(np.percentile(times, 95))) if len(times) else (math.nan, math.nan)


def stats(rows: list[dict]) -> dict:
    median, p95 = time_quantiles(rows)
    n = len(rows)
    return {'n': n,
            'ok': sum(r['ok'] for r in rows) / n if n else float('nan'),
            'ok_loose': sum(r['ok_loose'] for r in rows) / n if n else float('nan'),
            'top4': sum(r.get('top4_ok', False) for r in rows) / n if n else float('nan'),
            'marked_wrong': sum(r['success'] and not r['ok'] for r in rows) / n if n else float('nan'),
            'marked': sum(r['success'] for r in rows) / n if n else float('nan'),
            'median': median, 'p95': p95}


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
