"""The benchmark's worker processes: one (trial, method) localization per job. In a
module of its own because spawned workers cannot import functions from a __main__."""
from __future__ import annotations

import math
import time

import numpy as np

from ..core.localizer import Localizer
from ..core.outcome import Outcome
from ..core.scan import ScanError
from ..core.transform import pose_correct, pose_error

_MAPS = {}        # map name -> OccupancyMap, in each worker (set by worker_init)
_LOCALIZERS = {}  # per worker process


def localizer_of(trial) -> Localizer:
    """The trial's Localizer in this process: one per map, kept (a map of the trial's own - the
    unmapped suite - is built for it alone)."""
    if trial.own_map is not None:
        return Localizer(trial.own_map)
    if trial.map_name not in _LOCALIZERS:
        _LOCALIZERS[trial.map_name] = Localizer(_MAPS[trial.map_name])
    return _LOCALIZERS[trial.map_name]


def run_job(job):
    """One (trial, method) localization in a worker; returns a row."""
    trial_id, trial, method = job
    loc = localizer_of(trial)
    row = {'trial': trial_id, 'suite': trial.suite, 'map': trial.map_name, **trial.condition, 'method': method,
           'local_map_cells': trial.local_map_cells,
           'truth': [round(v, 4) for v in trial.truth.as_tuple()]}
    step = trial.condition.get('angle_step', 5)
    try:
        built = precomputed(loc, method)    # built once per map and worker, not in a trial's time
        if trial.points is not None:
            res = loc.localize_points(trial.points, method, step, base_T_laser=trial.base_T_laser)
        else:
            res = loc.localize(trial.scan, method, step, base_T_laser=trial.base_T_laser, region=trial.region)
    except Exception as e:   # a failure of a method on one trial is a data point, not a crash
        outcome = Outcome.UNUSABLE_SCAN if isinstance(e, ScanError) else Outcome.INTERNAL_ERROR
        return {**row, 'error': f'{type(e).__name__}: {e}', 'outcome': outcome.label, 'ok': False, 'ok_loose': False,
                'success': False, 'time_s': float('nan')}
    row.update(time_s=res.time_s, success=res.success, confidence=res.confidence,
               score=res.score if math.isfinite(res.score) else None, found=res.pose is not None,
               top4_ok=any(pose_correct(h.pose, trial.truth) for h in res.hypotheses[:4]),
               hyp_scores=[round(h.score, 4) for h in res.hypotheses[:4]], message=res.message.split(':')[0],
               twin='its twin' in res.message,
               outcome=res.outcome.label)
    row.update(built)
    if res.raw is not None:      # a thesis matcher checked on the map: its own verdict too (the thesis's numbers)
        row.update(raw_success=res.raw.success, raw_outcome=res.raw.outcome.label,
                   raw_ok=res.raw.pose is not None and pose_correct(res.raw.pose, trial.truth))
    search_s = getattr(res.search_stats, 'search_s', None)
    if search_s is not None:      # bnb: the search proper, apart from the fixed work around it
        row.update(search_s=search_s, expansions=res.search_stats.expansions, settled=res.search_stats.settled,
                   hypotheses=len(res.hypotheses), top_nodes=res.search_stats.top_nodes,
                   top_in_band=res.search_stats.top_in_band)
    if res.pose is None:
        row.update(ok=False, ok_loose=False)
    else:
        err = pose_error(res.pose, trial.truth)
        row.update(estimate=[round(v, 4) for v in res.pose.as_tuple()], err_xy=round(err[0], 4),
                   err_yaw_deg=round(err[1], 3), ok=pose_correct(res.pose, trial.truth),
                   ok_loose=pose_correct(res.pose, trial.truth, 0.5, 10.0))
        row.update(covariance_rows(res.pose, res.covariance, trial.truth))
    return row


def precomputed(loc: Localizer, method: str) -> dict:
    """The method's matcher (and its tracker) built for the trial's map; on the build, its
    seconds and the bytes it keeps (`nbytes`, where the matcher counts them) for the report's
    table of the thesis matchers' precomputation. Nothing when they were built before."""
    fresh = method not in loc.prepared()
    t0 = time.perf_counter()
    matcher = loc.matcher(method)
    seconds = time.perf_counter() - t0
    loc.tracker(method)
    if not fresh or method == 'bnb':
        return {}
    nbytes = getattr(matcher, 'nbytes', None)
    return {'build_s': round(seconds, 3), 'build_mb': None if nbytes is None else round(nbytes / 1e6, 2),
            'map_cells': loc.map.width * loc.map.height}


def covariance_rows(estimate, covariance, truth) -> dict:
    """The published covariance against the error (the calibration table, bench/calibration.py):
    its standard deviations and the error's squared Mahalanobis distance (x, y, yaw)."""
    cov = np.asarray(covariance, dtype=float)
    error = np.array([estimate.x - truth.x, estimate.y - truth.y,
                      math.remainder(estimate.yaw - truth.yaw, 2 * math.pi)])
    try:
        d2 = float(error @ np.linalg.solve(cov, error))
    except np.linalg.LinAlgError:
        d2 = math.inf
    return {'sigma_x': round(math.sqrt(max(cov[0, 0], 0.0)), 5), 'sigma_y': round(math.sqrt(max(cov[1, 1], 0.0)), 5),
            'sigma_yaw_deg': round(math.degrees(math.sqrt(max(cov[2, 2], 0.0))), 4),
            'err_x': round(abs(error[0]), 5), 'cov_d2': round(d2, 4) if math.isfinite(d2) else None}


def worker_init(maps, threads):
    """threads: each worker's share of the cores. OpenCV's threads and bnb's search
    threads follow cv2.setNumThreads, so every method gets the same share."""
    import cv2
    cv2.setNumThreads(threads)
    _MAPS.update(maps)
