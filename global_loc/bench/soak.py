"""The `soak` suite: the real server against the simulator node for many goals, with the
faults a deployed robot meets. Not a test: it reports figures for the report.

Processes: `ros2 run global_loc sim` (office, 40 Hz x 1081 beams over 270 deg) and
`ros2 run global_loc server` (max_search_s 1 s) on a private DDS domain; this process
sends the goals (an action client in its own rclpy context). The goal mix, seeded:
- plain bnb goals, publishing /initialpose; every 10th goal the robot is first kidnapped
  (teleported to a random free pose);
- every 10th a goal whose search ends at its time limit (the template matcher at a
  0.05 deg step: 7200 rotations), cancelled or not;
- every 7th a goal cancelled at a random moment (0.05 - 0.8 s after it was accepted;
  alternately bnb and the template matcher at 1 deg, which runs ~2 s);
- every 13th two goals at once (one must get `busy`);
- four times near the end (the last four of every goals/16-th goal), a SIGTERM
  mid-goal, then the server is started again: the first server process serves most
  of the run (its RSS is the memory figure).
Measured: success and wrong (marked success, > 0.2 m / 5 deg off the simulator's true
pose), every /initialpose checked against the true pose, the server's RSS (start /
middle / end after warm-up), cancel latency (cancel sent -> result received), goal
latency at the start and the end, SIGTERM exit time, crashes (a server exit code other
than 0, or a process that died on its own).
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np
from tqdm import tqdm

from ..core.map_io import load_map_yaml
from ..core.paths import default_map_yaml
from ..core.transform import pose_correct
from ..sim.raycast import sample_free_poses
from ..sim.simulator import BASE_T_LASER
from ..testing.ros_harness import Harness, rss_mb

WARM_UP_GOALS = 20


class SoakRun:
    """The processes of one soak run and the goals it sends, one method per kind of goal."""

    def __init__(self, seed: int, log_dir: str):
        from ..testing.processes import isolated_env, start_server, start_sim
        self.rng = np.random.default_rng(seed)
        self.kidnap_poses = sample_free_poses(load_map_yaml(default_map_yaml()), 200, self.rng, clearance=0.6)
        self.env, self.log_dir, self.start_server = isolated_env(), log_dir, start_server
        os.makedirs(log_dir, exist_ok=True)
        self.sim = start_sim(self.env, os.path.join(log_dir, 'sim.log'), 'rate_hz:=40.0', 'num_beams:=1081',
                             'fov_deg:=270.0', 'x:=3.0', 'y:=4.0', 'yaw:=0.7')
        self.servers = []
        self.server = self.new_server()
        self.h = Harness(self.env, 'global_loc_soak')
        deadline = time.monotonic() + 20.0     # every goal is checked against a true pose
        while self.h.truth is None and time.monotonic() < deadline:
            time.sleep(0.05)

    def new_server(self):
        # the simulator's laser sits BASE_T_LASER ahead of base_link (no tf2 here: the server is told)
        self.servers.append(self.start_server(self.env, os.path.join(self.log_dir, f'server{len(self.servers)}.log'),
                                              'max_search_s:=1.0', 'scan_timeout_s:=5.0', f'laser_x:={BASE_T_LASER.x}'))
        self.server = self.servers[-1]
        return self.server

    def restart(self, row: dict) -> None:
        """SIGTERM mid-goal, then start again."""
        handle = self.h.send(method='template_ccoeff', angle_step_deg=0.05)
        result_future = handle.get_result_async() if handle is not None else None
        time.sleep(0.3)
        t0 = time.monotonic()
        code = self.server.stop(timeout=10.0)
        res = self.h.wait(result_future, 3.0) if result_future is not None else None
        row.update(kind='restart', exit_s=time.monotonic() - t0, exit_code=code, answered=res is not None,
                   outcome=res.result.outcome if res else None)
        self.new_server()

    def limited(self, row: dict) -> None:
        """A goal that ends at the 1 s search limit (or a cancel)."""
        handle = self.h.send(method='template_ccoeff', angle_step_deg=0.05)
        res = self.h.wait(handle.get_result_async(), 30.0) if handle else None
        row.update(kind='limited', outcome=res.result.outcome if res else None)

    def cancel(self, row: dict, method: str) -> None:
        """A goal cancelled at a random moment."""
        handle = self.h.send(publish_initialpose=True, method=method, angle_step_deg=1.0)
        row['method'] = method
        if handle is not None:
            time.sleep(float(self.rng.uniform(0.05, 0.8)))
            result_future = handle.get_result_async()
            t0 = time.monotonic()
            handle.cancel_goal_async()
            res = self.h.wait(result_future, 10.0)
            row.update(kind='cancel', cancel_s=time.monotonic() - t0 if res else None,
                       outcome=res.result.outcome if res else None)

    def concurrent(self, row: dict) -> None:
        """Two clients at once."""
        a, b = self.h.send(publish_initialpose=True), self.h.send(publish_initialpose=True)
        outcomes = [self.h.wait(x.get_result_async(), 30.0) for x in (a, b) if x is not None]
        row.update(kind='concurrent', outcomes=[r.result.outcome for r in outcomes if r])

    def plain(self, row: dict) -> None:
        """A bnb goal publishing /initialpose, its answer checked against the true pose."""
        truth = self.h.truth
        t0 = time.monotonic()
        handle = self.h.send(publish_initialpose=True)
        res = self.h.wait(handle.get_result_async(), 30.0) if handle else None
        row.update(kind='plain', latency_s=time.monotonic() - t0, answered=res is not None)
        if res is not None:
            r = res.result
            row.update(outcome=r.outcome, success=bool(r.success))
            if len(r.hypotheses.poses) and truth is not None:
                estimate = self.h.pose_from_msg(r.pose.pose.pose)
                row.update(ok=pose_correct(estimate, truth), estimate=estimate.as_tuple(),
                           truth=truth.as_tuple(), truth_after=self.h.truth.as_tuple())

    def processes(self, row: dict) -> None:
        """The server's memory and whether both processes live; a crash noted, a new server started."""
        row['rss_mb'] = rss_mb(self.server.proc.pid)
        row['server'] = len(self.servers) - 1
        row['server_alive'] = self.server.proc.poll() is None
        row['sim_alive'] = self.sim.proc.poll() is None
        if not row['server_alive']:
            row['crash_code'] = self.server.proc.returncode
            self.new_server()

    def close(self) -> list[dict]:
        self.h.close()
        t0 = time.monotonic()
        code = self.server.stop(timeout=10.0)
        return [{'suite': 'soak', 'kind': 'final_stop', 'exit_s': time.monotonic() - t0, 'exit_code': code},
                {'suite': 'soak', 'kind': 'sim_stop', 'exit_code': self.sim.stop(timeout=10.0)}]


def soak_rows(goals: int, seed: int, log_dir: str) -> list[dict]:
    run, rows = SoakRun(seed, log_dir), []
    step = max(5, goals // 16)
    restarts = {goals - 1 - k * step for k in range(4)}
    try:
        for i in tqdm(range(goals), desc='soak goals', file=sys.stderr):
            row = {'suite': 'soak', 'goal': i}
            if i % 10 == 5:
                run.h.kidnap(run.kidnap_poses[int(run.rng.integers(len(run.kidnap_poses)))])
                row['kidnap'] = True
            if i in restarts:
                run.restart(row)
            elif i % 10 == 3:
                run.limited(row)
            elif i % 7 == 2:
                run.cancel(row, 'bnb' if (i // 7) % 2 else 'template_ccoeff')
            elif i % 13 == 6:
                run.concurrent(row)
            else:
                run.plain(row)
            run.processes(row)
            rows.append(row)
        time.sleep(0.5)
        rows.append({'suite': 'soak', 'kind': 'summary', 'initialposes': run.h.initialposes,
                     'wrong_initialposes': run.h.wrong_initialposes})
    finally:
        rows += run.close()
    return rows


def soak_summary(rows: list[dict]) -> dict:
    """The figures the report prints."""
    plain = [r for r in rows if r.get('kind') == 'plain']
    answered = [r for r in plain if r.get('answered')]
    # RSS per server process (a restart starts a new one), after its first WARM_UP_GOALS goals
    segments = {}
    for r in rows:
        if 'rss_mb' in r and math.isfinite(r['rss_mb']) and r.get('kind') != 'restart':
            segments.setdefault(r['server'], []).append(r['rss_mb'])
    warm_segments = [v[WARM_UP_GOALS:] for v in segments.values() if len(v) > WARM_UP_GOALS]
    warm = max(warm_segments, key=len) if warm_segments else []
    growth = [100.0 * (v[-1] - v[0]) / v[0] for v in warm_segments]
    # latency of the cancels that ended a goal (the others came after the goal had finished)
    cancels = [r['cancel_s'] for r in rows if r.get('kind') == 'cancel' and r.get('outcome') == 15]
    restarts = [r for r in rows if r.get('kind') == 'restart']
    stops = restarts + [r for r in rows if r.get('kind') == 'final_stop']
    lat = [r['latency_s'] for r in answered]
    summary = next((r for r in rows if r.get('kind') == 'summary'), {})
    n = len([r for r in rows if 'goal' in r])
    return {
        'goals': n, 'plain': len(plain), 'answered': len(answered),
        'success': sum(bool(r.get('success')) for r in answered),
        'success_right': sum(bool(r.get('success')) and bool(r.get('ok')) for r in answered),
        'success_wrong': sum(bool(r.get('success')) and r.get('ok') is False for r in answered),
        'initialposes': summary.get('initialposes'), 'wrong_initialposes': summary.get('wrong_initialposes'),
        'rss_start_mb': warm[0] if warm else None, 'rss_middle_mb': warm[len(warm) // 2] if warm else None,
        'rss_end_mb': warm[-1] if warm else None, 'rss_max_mb': max(warm) if warm else None,
        'rss_goals': len(warm), 'rss_growth_pct': [round(g, 1) for g in growth],
        'restart_goals': [r['goal'] for r in rows if r.get('kind') == 'restart'],
        'cancel_goals': sum(r.get('kind') == 'cancel' for r in rows), 'cancels': len(cancels),
        'cancel_median_s': float(np.median(cancels)) if cancels else None,
        'cancel_p95_s': float(np.percentile(cancels, 95)) if cancels else None,
        'cancel_max_s': max(cancels) if cancels else None,
        'cancels_unanswered': sum(r.get('kind') == 'cancel' and r.get('cancel_s') is None for r in rows),
        'latency_first100_median_s': float(np.median(lat[:100])) if lat else None,
        'latency_last100_median_s': float(np.median(lat[-100:])) if lat else None,
        'limited': sum(r.get('kind') == 'limited' for r in rows),
        'limited_incomplete': sum(r.get('kind') == 'limited' and r.get('outcome') == 4 for r in rows),
        'concurrent': sum(r.get('kind') == 'concurrent' for r in rows),
        'restarts': len(restarts), 'restart_answered': sum(bool(r.get('answered')) for r in restarts),
        'exit_max_s': max((r['exit_s'] for r in stops), default=None),
        'exit_codes': sorted({r['exit_code'] for r in stops}),
        'crashes': sum('crash_code' in r for r in rows) + sum(r.get('kind') == 'sim_stop' and r['exit_code'] != 0
                                                               for r in rows),
    }
