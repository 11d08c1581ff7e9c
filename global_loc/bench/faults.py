"""The `faults` suite: what changes while the server runs (issue 24), scripted against the
real `ros2 run global_loc server` and `ros2 run global_loc sim` processes (office, 10 Hz
x 541 beams over 270 deg) on a private DDS domain, each scenario run several times with
seeds. A goal loop in this process sends bnb (or template) goals that publish their pose,
one after another, while the scenario injects its fault:

- map_republished: use_map_topic; the office republished on /map at random moments and
  sizes (padded at the top and right, the same frame), and a big map of the office drawn
  5 m off followed at once by the office (the newest received must win);
- localizer_late / localizer_drops: auto_relocalize with a stand-in localizer (AMCL's part:
  /amcl_pose from the last /initialpose it took; ros_harness.StandInLocalizer) started
  2-6 s late, or dropping half of what it receives and sends; no goals;
- laser_late: the simulator started 2-6 s after the server; laser_stops: SIGTERM to the
  simulator mid-goal, started again 1-4 s later at another pose; sim_killed: SIGKILL, at once;
- lifecycle_mid_goal: deactivate (-> cleanup -> configure) -> activate on ~/change_state
  mid-goal, twice;
- lifecycle_by_id: nav2's lifecycle_manager's requests by transition id mid-goal: its
  start-up (configure, activate) sent to a server already up through autostart, an id no
  state has and cleanup while active (each must be answered false, the server serving
  on), then deactivate -> cleanup -> configure -> activate;
- unprepared_method: goals naming features_sift (not prepared: refused at once, never
  built inside a goal) among slow template goals, canceled 0.3-1.5 s after they are sent,
  and deactivate -> activate mid-goal;
- params_mid_goal: three /global_loc_server/set_parameters calls mid-goal, live values and
  refused ones;
- client_killed: `test_global_loc` SIGINT-ed and SIGKILL-ed mid-goal (its process group,
  as a terminal does), then the goal loop.

Per run: goals sent and answered; /initialpose messages and the wrong ones (farther than
core.transform.pose_correct from the simulator's /sim/true_pose at the pose's stamp, the
scan's); localized results that are wrong; hangs (a goal unanswered GOAL_BOUND_S after it
was sent, a service call unanswered, a process not ended EXIT_BOUND_S after its signal);
recovery: from the end of the fault (the last thing the scenario did) to the next right
localization (a goal localized right, a right pose published or taken by the localizer);
crashes (the server exited before the run's end); goals that outlived their configuration
(in flight when a deactivate was sent, answered after it was, not `canceled`); non-finite
poses (published or in a result); the slowest cancel (sent to the goal's result).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter

import numpy as np
from tqdm import tqdm

from ..core.map_io import OccupancyMap, load_map_yaml, make_map
from ..core.outcome import Outcome
from ..core.paths import default_map_yaml
from ..core.transform import Rigid2D
from ..sim.simulator import BASE_T_LASER
from .ros_harness import Harness, StandInLocalizer

GOAL_BOUND_S = 20.0      # a goal waits <= 2 s for a scan and searches <= 2 s: unanswered by then, a hang
EXIT_BOUND_S = 10.0      # a process signalled to end
SERVER_PARAMS = ('max_search_s:=2.0', 'scan_timeout_s:=2.0', f'laser_x:={BASE_T_LASER.x}')
AUTO_RELOCALIZE = ('auto_relocalize:=true', 'relocalize.start_delay_s:=0.5', 'relocalize.settle_s:=2.0',
                   'relocalize.min_interval_s:=1.0', 'relocalize.max_attempts:=20')
# office places where both goal kinds are right and confident on a fault-free simulated scan
# (bnb 6 of 6, template at 2 deg 8 of 8): a wrong pose is the fault's, not the matcher's
POSES = (Rigid2D(20.675, 5.225, 0.0), Rigid2D(3.975, 14.625, 2.499), Rigid2D(2.025, 10.375, -0.044),
         Rigid2D(22.075, 4.925, 0.349))
BNB, TEMPLATE = {'method': 'bnb'}, {'method': 'template_ccoeff', 'angle_step_deg': 2.0}
SIFT = {'method': 'features_sift'}          # not in the server's default `methods`
SLOW_TEMPLATE = {'method': 'template_ccoeff', 'angle_step_deg': 0.5, 'cancel_after_s': (0.3, 1.5)}


class Run:
    """One scenario run: its processes, the harness, the goal loop and what they saw."""

    def __init__(self, scenario: str, seed: int, log_dir: str):
        from ..ros.processes import isolated_env
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
        from ..ros.processes import start_server
        self.processes['server'] = start_server(self.env, self.log('server'), *SERVER_PARAMS, *params)
        return self.processes['server']

    def sim(self, pose: Rigid2D | None = None, name: str = 'sim'):
        from ..ros.processes import start_sim
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


# ---- scenarios --------------------------------------------------------------------------
def padded(office: OccupancyMap, rng) -> OccupancyMap:
    """The office with unknown cells added at the top and right: another size, the same frame."""
    top, right = (int(v) for v in rng.integers(0, 600, 2))
    grid = np.pad(office.occupancy, ((top, 0), (0, right)), constant_values=-1)
    return make_map(grid, office.resolution, office.origin, f'office padded to {grid.shape[1]} x {grid.shape[0]}')


def shifted(office: OccupancyMap, rng, shift_m: float = 5.0) -> OccupancyMap:
    """The office drawn `shift_m` further along x in a big map (slow to prepare): a scan
    of the office localizes that far off in it."""
    size = int(rng.integers(900, 1500))
    big = np.full((size, size), -1, dtype=office.occupancy.dtype)
    dx, (h, w) = int(round(shift_m / office.resolution)), office.occupancy.shape
    big[size - h:, dx:dx + w] = office.occupancy       # row 0 is the top: keep the bottom-left origin
    return make_map(big, office.resolution, office.origin, f'office 5 m off in {size} x {size}')


def map_republished(run: Run) -> None:
    office = load_map_yaml(default_map_yaml())
    run.server('use_map_topic:=true')
    run.sim(POSES[0])
    run.h.publish_map(office)
    run.loop(BNB)
    for kind in run.rng.permutation(['race', 'race', 'padded']):     # each run has the race of issue 24 item 1
        run.sleep_between(0.5, 3.0)
        maps = [shifted(office, run.rng)] if kind == 'race' else []
        for m in maps + [padded(office, run.rng)]:
            run.h.publish_map(m)
        run.mark('published ' + ', then '.join(m.source for m in maps + [m]))
    time.sleep(8.0)


def localizer_late(run: Run) -> None:
    run.server(*AUTO_RELOCALIZE)
    run.sim()
    run.sleep_between(2.0, 6.0)
    run.localizer = StandInLocalizer(run.h, np.random.default_rng(run.seed + 2))
    run.mark('stand-in localizer started')
    run.until(lambda: any(ok for _, ok in run.localizer.taken), 30.0)
    time.sleep(2.0)


def localizer_drops(run: Run) -> None:
    run.server(*AUTO_RELOCALIZE)
    run.sim()
    run.localizer = StandInLocalizer(run.h, np.random.default_rng(run.seed + 2), drop=0.5)
    run.mark('stand-in localizer dropping half its messages started')
    run.until(lambda: any(ok for _, ok in run.localizer.taken), 30.0)
    time.sleep(4.0)


def laser_late(run: Run) -> None:
    run.server()
    run.loop(BNB)
    run.sleep_between(2.0, 6.0)
    run.sim()
    run.mark('simulator started')
    time.sleep(6.0)


def laser_stopped(run: Run, sig: signal.Signals) -> None:
    run.server()
    run.sim()
    run.loop(BNB, TEMPLATE)
    run.sleep_between(1.5, 3.0)
    if sig == signal.SIGKILL:
        run.kill('sim')
    else:
        run.stop('sim')
        run.sleep_between(1.0, 4.0)
    run.sim()
    run.mark(f'simulator stopped ({sig.name}) and started again')
    time.sleep(6.0)


def lifecycle_mid_goal(run: Run) -> None:
    from lifecycle_msgs.msg import Transition as T
    run.server()
    run.sim()
    run.loop(BNB, TEMPLATE)
    for _ in range(2):
        run.sleep_between(0.5, 2.0)
        steps = [T.TRANSITION_DEACTIVATE, T.TRANSITION_ACTIVATE] if run.rng.uniform() < 0.5 else \
            [T.TRANSITION_DEACTIVATE, T.TRANSITION_CLEANUP, T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE]
        for step in steps:
            run.transition(step)
            run.sleep_between(0.0, 0.8)
        run.mark(f'lifecycle {steps}')
    time.sleep(6.0)


def lifecycle_by_id(run: Run) -> None:
    from lifecycle_msgs.msg import Transition as T
    run.server()          # autostart: active before the lifecycle manager's start-up
    run.sim()
    run.loop(BNB, TEMPLATE)
    for _ in range(2):
        run.sleep_between(0.5, 2.0)
        for step in (T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE, 99, T.TRANSITION_CLEANUP):
            run.transition(step, expected=False)        # none is a transition of the active state
        run.sleep_between(0.0, 0.8)
        for step in (T.TRANSITION_DEACTIVATE, T.TRANSITION_CLEANUP, T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE):
            run.transition(step)
            run.sleep_between(0.0, 0.5)
        run.mark('lifecycle by id')
    time.sleep(6.0)


def unprepared_method(run: Run) -> None:
    from lifecycle_msgs.msg import Transition as T
    run.server()
    run.sim()
    run.loop(SIFT, SLOW_TEMPLATE, BNB)
    for _ in range(2):
        run.sleep_between(1.0, 3.0)
        for step in (T.TRANSITION_DEACTIVATE, T.TRANSITION_ACTIVATE):
            run.transition(step)
            run.sleep_between(0.0, 0.5)
        run.mark('deactivate -> activate')
    time.sleep(6.0)


PARAMETER_SETS = ({'method': 'template_ccoeff'}, {'method': 'bnb'}, {'max_search_s': 0.5}, {'max_search_s': 3.0},
                  {'scan_timeout_s': 1.0}, {'angle_step_deg': 3.0}, {'bnb.keep_ratio': 5.0},
                  {'bnb.max_nodes': 50}, {'method': 'no_such_matcher'})


def params_mid_goal(run: Run) -> None:
    run.server()
    run.sim()
    run.loop(BNB, TEMPLATE)
    for _ in range(3):
        run.sleep_between(0.3, 1.5)
        values = PARAMETER_SETS[int(run.rng.integers(len(PARAMETER_SETS)))]
        results = run.h.set_parameters(values)
        if results is None:
            run.hangs.append(f'set_parameters {values}: no answer within 15 s')
        run.mark(f'set {values}: {"no answer" if results is None else [r.successful for r in results]}')
    time.sleep(6.0)


def client_killed(run: Run) -> None:
    from ..ros.processes import start_client
    server = run.server()
    run.sim()
    for sig in (signal.SIGINT, signal.SIGKILL)[::int(run.rng.choice([1, -1]))]:
        goals_before = server.output().count('localizing (goal)')
        with open(run.log(f'client_{sig.name}'), 'w') as log:
            client = start_client(run.env, '--method', 'template_ccoeff', '--angle-step', '1', '--timeout', '3',
                                  stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
            run.until(lambda n=goals_before: server.output().count('localizing (goal)') > n, 20.0)
            run.sleep_between(0.05, 1.0)
            os.killpg(client.pid, sig)
            t0 = time.monotonic()
            try:
                client.wait(EXIT_BOUND_S)
            except subprocess.TimeoutExpired:
                run.hangs.append(f'client: no exit within {EXIT_BOUND_S} s of {sig.name}')
                os.killpg(client.pid, signal.SIGKILL)
                client.wait()
            run.mark(f'client {sig.name}: exit {client.returncode} after {time.monotonic() - t0:.2f} s')
    run.loop(BNB)
    time.sleep(6.0)


SCENARIOS = {'map_republished': map_republished, 'localizer_late': localizer_late,
             'localizer_drops': localizer_drops, 'laser_late': laser_late,
             'laser_stops': lambda run: laser_stopped(run, signal.SIGTERM),
             'sim_killed': lambda run: laser_stopped(run, signal.SIGKILL),
             'lifecycle_mid_goal': lifecycle_mid_goal, 'lifecycle_by_id': lifecycle_by_id,
             'unprepared_method': unprepared_method, 'params_mid_goal': params_mid_goal,
             'client_killed': client_killed}


def fault_rows(runs: int, seed: int, log_dir: str, scenarios=tuple(SCENARIOS)) -> list[dict]:
    """Each scenario `runs` times (seeds seed + 100 * scenario + run): one row a run."""
    rows = []
    todo = [(i, name, k) for i, name in enumerate(SCENARIOS) if name in scenarios for k in range(runs)]
    for i, name, k in tqdm(todo, desc='fault runs', file=sys.stderr):
        run = Run(name, seed + 100 * i + k, os.path.join(log_dir, f'{name}_{k}'))
        error = None
        try:
            SCENARIOS[name](run)
        except Exception as e:       # a process that did not start: the run's row says so
            error = f'{type(e).__name__}: {str(e)[:300]}'
        row = run.finish()
        row.update(run=k, error=error)
        rows.append(row)
    return rows
