"""One run of a fault scenario (bench/faults.py): its server and simulator processes, the
harness, the goal loop, the lifecycle requests, and the row of what they saw."""
from __future__ import annotations

import os
import signal
import threading
import time
from collections import Counter

import numpy as np

from ..core.outcome import Outcome
from ..core.transform import Rigid2D
from ..sim.simulator import BASE_T_LASER
from ..testing.ros_harness import Harness

GOAL_BOUND_S = 20.0      # a goal waits <= 2 s for a scan and searches <= 2 s: unanswered by then, a hang
EXIT_BOUND_S = 10.0      # a process signalled to end
SERVER_PARAMS = ('max_search_s:=2.0', 'scan_timeout_s:=2.0', f'laser_x:={BASE_T_LASER.x}')
# office places where both goal kinds are right and confident on a fault-free simulated scan
# (bnb 6 of 6, template at 2 deg 8 of 8): a wrong pose is the fault's, not the matcher's
POSES = (Rigid2D(20.675, 5.225, 0.0), Rigid2D(3.975, 14.625, 2.499), Rigid2D(2.025, 10.375, -0.044),
         Rigid2D(22.075, 4.925, 0.349))

class Run:
    """One scenario run: its processes, the harness, the goal loop and what they saw."""

    def __init__(self, scenario: str, seed: int, log_dir: str):
        from ..testing.processes import isolated_env
        self.scenario, self.seed, self.log_dir = scenario, seed, log_dir
        self.rng = np.random.default_rng(seed)
        self.env = isolated_env()
        os.makedirs(log_dir, exist_ok=True)
        self.processes: dict[str, object] = {}
        self.h = Harness(self.env, 'global_loc_faults')
        self.goals, self.hangs, self.notes = [], [], []
        self.deactivations = []        # (sent, answered) monotonic times of each deactivate
        self.t_start, self.fault_end = time.monotonic(), None
        self.localizer = None
        self._loop_stop, self._loop = threading.Event(), None

    def log(self, name: str) -> str:
        return os.path.join(self.log_dir, f'{name}.log')

    def server(self, *params):
        from ..testing.processes import start_server
        self.processes['server'] = start_server(self.env, self.log('server'), *SERVER_PARAMS, *params)
        return self.processes['server']

    def sim(self, pose: Rigid2D | None = None, name: str = 'sim'):
        from ..testing.processes import start_sim
        pose = pose or POSES[int(self.rng.integers(len(POSES)))]
        self.processes[name] = start_sim(self.env, self.log(name), f'x:={pose.x}', f'y:={pose.y}', f'yaw:={pose.yaw}',
                                         f'seed:={int(self.rng.integers(1000))}')
        return self.processes[name]

    def stop(self, name: str) -> None:
        """SIGTERM to a process; longer than EXIT_BOUND_S to end is a hang."""
        t0 = time.monotonic()
        code = self.processes.pop(name).stop(timeout=EXIT_BOUND_S)
        if time.monotonic() - t0 > EXIT_BOUND_S:
            self.hangs.append(f'{name}: no exit within {EXIT_BOUND_S} s of SIGTERM')
        if code != 0:
            self.notes.append(f'{name} exit code {code}')

    def kill(self, name: str) -> None:
        proc = self.processes.pop(name)
        os.killpg(proc.proc.pid, signal.SIGKILL)
        proc.proc.wait()
        proc.log.close()

    def mark(self, note: str) -> None:
        """The fault's end (for now: the last one marked wins)."""
        self.fault_end = time.monotonic()
        self.notes.append(f'{self.fault_end - self.t_start:.1f} s: {note}')

    # ---- goals ----------------------------------------------------------------------------
    def goal(self, fields: dict) -> None:
        """One goal to its end; `cancel_after_s` (low, high): canceled that long after it was sent."""
        t0 = time.monotonic()
        fields = dict(fields)
        cancel_after = fields.pop('cancel_after_s', None)
        record = {'t0': t0, 'method': fields['method']}
        self.goals.append(record)
        handle = self.h.send(timeout_s=2.0, publish_initialpose=True, **fields)
        if handle is None or not handle.accepted:
            self.hangs.append(f'goal at {t0 - self.t_start:.1f} s: not accepted within 20 s')
            return
        done = handle.get_result_async()
        if cancel_after is not None and self.h.wait(done, float(self.rng.uniform(*cancel_after))) is None:
            record['canceled_at'] = time.monotonic()
            handle.cancel_goal_async()
        res = self.h.wait(done, GOAL_BOUND_S)
        record['t1'] = time.monotonic()
        if 'canceled_at' in record:
            record['cancel_s'] = record['t1'] - record['canceled_at']
        if res is None:
            self.hangs.append(f'goal at {t0 - self.t_start:.1f} s ({fields}): no result within {GOAL_BOUND_S} s')
            return
        r = res.result
        record.update(outcome=Outcome(r.outcome).label, success=bool(r.success))
        record['nonfinite'] = len(r.hypotheses.poses) > 0 and not self.h.pose_from_msg(r.pose.pose.pose).is_finite()
        if r.success and len(r.hypotheses.poses):
            pose = self.h.pose_from_msg(r.pose.pose.pose)
            record['ok'] = self.h.right_at(pose, r.scan_stamp)
            if record['ok'] is False:
                record.update(pose=pose.as_tuple(), truth=self.h.truth_at(r.scan_stamp).as_tuple(),
                              stamp_ns=r.scan_stamp.sec * 10 ** 9 + r.scan_stamp.nanosec, message=r.message)

    def serving(self, *mix: dict) -> None:
        """The server, then the simulator, started; goals of `mix` running (loop)."""
        self.server()
        self.sim()
        self.loop(*mix)

    def loop(self, *mix: dict) -> None:
        """Goals one after another in a background thread, each of a random kind of `mix`."""
        rng = np.random.default_rng(self.seed + 1)

        def run():
            while not self._loop_stop.is_set():
                self.goal(mix[int(rng.integers(len(mix)))])
                time.sleep(0.2)      # a refused goal ends at once: no flood
        self._loop = threading.Thread(target=run, daemon=True)
        self._loop.start()

    def transition(self, step: int, expected: bool = True) -> None:
        """A lifecycle transition by id; an answer other than `expected` is noted, none is a hang."""
        sent = time.monotonic()
        ok = self.h.change_state(step)
        if step == 4:          # lifecycle_msgs Transition.TRANSITION_DEACTIVATE
            self.deactivations.append((sent, time.monotonic()))
        if ok is None:
            self.hangs.append(f'change_state {step}: no answer within 15 s')
        elif ok != expected:
            self.notes.append(f'change_state {step}: {ok}, expected {expected}')

    def sleep_between(self, low: float, high: float) -> None:
        time.sleep(float(self.rng.uniform(low, high)))

    def until(self, condition, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not condition() and time.monotonic() < deadline:
            time.sleep(0.05)
        return condition()

    # ---- the row ----------------------------------------------------------------------------
    def finish(self) -> dict:
        self._loop_stop.set()
        if self._loop is not None:
            self._loop.join(GOAL_BOUND_S + 45.0)
        server = self.processes.get('server')
        crashed = server is not None and server.proc.poll() is not None
        for name in list(self.processes):
            self.stop(name)
        taken = list(self.localizer.taken) if self.localizer else []
        if self.localizer:
            self.localizer.close()
        self.h.close()
        answered = [g for g in self.goals if 'outcome' in g]
        rights = [g['t1'] for g in answered if g.get('ok')] + [t for t, ok in self.h.published + taken if ok]
        after = [t - self.fault_end for t in rights if self.fault_end is not None and t >= self.fault_end]
        logs = ''.join(open(os.path.join(self.log_dir, f)).read() for f in os.listdir(self.log_dir))
        return {'suite': 'faults', 'scenario': self.scenario, 'seed': self.seed, 'goals': len(self.goals),
                'answered': len(answered), 'outcomes': dict(Counter(g['outcome'] for g in answered)),
                'poses': self.h.initialposes, 'wrong_poses': self.h.wrong_initialposes,
                'unchecked_poses': sum(ok is None for _, ok in self.h.published),
                'wrong_results': sum(g.get('ok') is False for g in answered),
                'taken': len(taken), 'hangs': len(self.hangs), 'hang_notes': self.hangs,
                'recovery_s': round(min(after), 3) if after else None, 'notes': self.notes,
                'wrong': self.h.wrong + [g for g in answered if g.get('ok') is False],
                'tracebacks': logs.count('Traceback'), 'wall_s': round(time.monotonic() - self.t_start, 1),
                'crashes': int(crashed), 'outlived': sum(self.outlived(g) for g in answered),
                'nonfinite_poses': self.h.nonfinite + sum(bool(g.get('nonfinite')) for g in answered),
                'cancel_max_s': round(max((g['cancel_s'] for g in answered if 'cancel_s' in g), default=0.0), 3)}

    def outlived(self, goal: dict) -> bool:
        """In flight when a deactivate was sent, answered after it was, and not canceled."""
        return goal['outcome'] != 'canceled' and any(goal['t0'] < sent and goal['t1'] > answered
                                                     for sent, answered in self.deactivations)
