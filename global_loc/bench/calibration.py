"""Whether the published covariance means what it says: per suite, over bnb's confident
answers, how often the truth lies inside the 1 sigma and 2 sigma ellipsoids of (x, y,
yaw) - the squared Mahalanobis distance of the error against the chi-square quantiles
with 3 degrees of freedom of 68.3% and 95.4% (ideal: those shares) - and the median
sigma against the median error (AMCL spreads its particles by that covariance)."""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from .tables import group, pct

ONE_SIGMA = float(chi2.ppf(0.6827, 3))     # 3.53
TWO_SIGMA = float(chi2.ppf(0.9545, 3))     # 8.02


def calibration_stats(rows: list[dict]) -> dict:
    """n, 1 sigma and 2 sigma coverage, median sigma_x and |error x|, median sigma_yaw and
    |error yaw| of the rows that carry a covariance check (confident answers)."""
    rr = [r for r in rows if r.get('success') and r.get('cov_d2') is not None]
    if not rr:
        return {'n': 0}
    d2 = np.array([r['cov_d2'] for r in rr])
    return {'n': len(rr), 'one': float(np.mean(d2 <= ONE_SIGMA)), 'two': float(np.mean(d2 <= TWO_SIGMA)),
            'sigma_x': float(np.median([r['sigma_x'] for r in rr])),
            'err_x': float(np.median([r['err_x'] for r in rr])),
            'sigma_yaw': float(np.median([r['sigma_yaw_deg'] for r in rr])),
            'err_yaw': float(np.median([r['err_yaw_deg'] for r in rr]))}


def calibration_section(rows: list[dict]) -> list[str]:
    """The calibration table: one line per suite, bnb's confident answers."""
    lines = ['## Covariance calibration', '',
             'bnb\'s confident answers per suite: the share whose truth lies inside the published covariance\'s '
             f'1 sigma / 2 sigma ellipsoid of (x, y, yaw) (squared Mahalanobis distance <= {ONE_SIGMA:.2f} / '
             f'{TWO_SIGMA:.2f}, chi-square with 3 degrees of freedom; ideal 68% / 95%), and the median sigma beside '
             'the median error (bench/calibration.py).', '',
             '| suite | confident answers | inside 1 sigma | inside 2 sigma | median sigma x [m] | median error x [m] '
             '| median sigma yaw [deg] | median error yaw [deg] |', '|---|---|---|---|---|---|---|---|']
    for suite, rr in sorted(group([r for r in rows if r['method'] == 'bnb'], lambda r: r['suite']).items()):
        s = calibration_stats(rr)
        if s['n']:
            lines.append(f"| {suite} | {s['n']} | {pct(s['one'])} | {pct(s['two'])} | {s['sigma_x']:.4f} | "
                         f"{s['err_x']:.4f} | {s['sigma_yaw']:.3f} | {s['err_yaw']:.3f} |")
    return lines + ['']
