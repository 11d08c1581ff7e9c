"""The `faults` suite: what changes while the server runs, scripted against the
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
  as a terminal does), then the goal loop;
- stored_pose_unreadable: the stored-pose file a FIFO or deeply nested brackets: the
  start-up searches in full, goals are served;
- stored_pose_prior: goals with a search prior around the robot (their answers must not be
  stored), then the robot carried elsewhere and the server restarted (the stored pose must
  not be confirmed there: a wrong /initialpose would count);
- hostile_map: the map YAML a "billion laughs" file: the map is refused at once, goals are
  refused, then the server cleaned up, map_yaml set to the office, configured and activated
  again, and it localizes.

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
import time

import numpy as np
from tqdm import tqdm

from ..core.map_io import OccupancyMap, load_map_yaml, make_map
from ..core.paths import default_map_yaml
from ..testing.ros_harness import StandInLocalizer
from .fault_run import EXIT_BOUND_S, POSES, Run

AUTO_RELOCALIZE = ('auto_relocalize:=true', 'relocalize.start_delay_s:=0.5', 'relocalize.settle_s:=2.0',
                   'relocalize.min_interval_s:=1.0', 'relocalize.max_attempts:=20')
BNB, TEMPLATE = {'method': 'bnb'}, {'method': 'template_ccoeff', 'angle_step_deg': 2.0}
SIFT = {'method': 'features_sift'}          # not in the server's default `methods`
SLOW_TEMPLATE = {'method': 'template_ccoeff', 'angle_step_deg': 0.5, 'cancel_after_s': (0.3, 1.5)}


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
    for kind in run.rng.permutation(['race', 'race', 'padded']):     # each run has the race of a goal with a map change
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
    run.serving(BNB, TEMPLATE)
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
    run.serving(BNB, TEMPLATE)
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
    run.serving(BNB, TEMPLATE)          # autostart: active before the lifecycle manager's start-up
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
    run.serving(SIFT, SLOW_TEMPLATE, BNB)
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
    run.serving(BNB, TEMPLATE)
    for _ in range(3):
        run.sleep_between(0.3, 1.5)
        values = PARAMETER_SETS[int(run.rng.integers(len(PARAMETER_SETS)))]
        results = run.h.set_parameters(values)
        if results is None:
            run.hangs.append(f'set_parameters {values}: no answer within 15 s')
        run.mark(f'set {values}: {"no answer" if results is None else [r.successful for r in results]}')
    time.sleep(6.0)


def client_killed(run: Run) -> None:
    from ..testing.processes import start_client
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


def stored_pose_unreadable(run: Run) -> None:
    """The stored-pose file is a FIFO (reading it would block the start-up and every goal
    after it) or a file of deeply nested brackets (a parser's recursion): the start-up must
    search in full and the goals be served."""
    path = os.path.join(run.log_dir, 'stored_pose.json')
    if os.path.lexists(path):      # a log folder of an earlier benchmark run
        os.unlink(path)
    if run.seed % 2:       # the runs alternate between the two kinds
        os.mkfifo(path)
        kind = 'a FIFO'
    else:
        with open(path, 'w') as f:
            f.write('[' * 100_000 + ']' * 100_000)
        kind = 'nested brackets'
    run.sim()
    run.server(f'stored_pose_file:={path}')
    run.mark(f'server started with a stored-pose file of {kind}')
    run.loop(BNB)
    time.sleep(8.0)


def stored_pose_prior(run: Run) -> None:
    """Goals with a search prior around the robot are confident within the prior only: the
    stored pose must stay the start-up's (a full search). The robot is then carried to
    another place and the server restarted: the stored pose must not be confirmed there."""
    from geometry_msgs.msg import Pose2D
    path = os.path.join(run.log_dir, 'stored_pose.json')
    if os.path.lexists(path):
        os.unlink(path)
    here, there = (POSES[int(i)] for i in run.rng.choice(len(POSES), 2, replace=False))
    run.sim(here)
    server = run.server(f'stored_pose_file:={path}')
    run.until(lambda: 'start-up: ' in server.output(), 30.0)
    kept = open(path).read() if os.path.exists(path) else None
    prior = {'method': 'bnb', 'search_center': Pose2D(x=here.x, y=here.y, theta=here.yaw), 'search_radius_m': 1.5}
    for _ in range(3):
        run.goal(prior)
    if (open(path).read() if os.path.exists(path) else None) != kept:
        run.h.wrong.append({'what': 'an answer confident only within a search prior was stored'})
    run.stop('server')
    run.stop('sim')
    run.sim(there)
    server = run.server(f'stored_pose_file:={path}')
    run.until(lambda: 'start-up: ' in server.output(), 30.0)
    run.mark('carried to another place while the server was down, server restarted')
    time.sleep(2.0)      # the harness's action client rediscovers the new server (it does not resend)
    run.loop(BNB)
    time.sleep(6.0)


def hostile_map(run: Run) -> None:
    """The map YAML is a "billion laughs" file (a few hundred bytes of nested aliases): the
    map must be refused at once, naming the file, with goals refused; map_yaml set to the
    office and the server configured again (deactivate, cleanup, configure, activate), it
    localizes."""
    from lifecycle_msgs.msg import Transition as T
    path = os.path.join(run.log_dir, 'laughs.yaml')
    lines = ['a0: &a0 "lol"'] + [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 10)}]' for i in range(1, 10)]
    with open(path, 'w') as f:
        f.write('\n'.join(lines + ['image: *a9', 'resolution: 0.05', 'origin: [0, 0, 0]',
                                   'occupied_thresh: 0.65', 'free_thresh: 0.2', '']))
    run.sim()
    server = run.server(f'map_yaml:={path}')
    if not run.until(lambda: 'map not loaded' in server.output(), 10.0):
        run.hangs.append('a billion-laughs map YAML: no "map not loaded" within 10 s')
    run.loop(BNB)
    run.sleep_between(1.0, 2.0)
    for step in (T.TRANSITION_DEACTIVATE, T.TRANSITION_CLEANUP):      # map_yaml is read at configure
        run.transition(step)
    results = run.h.set_parameters({'map_yaml': default_map_yaml()})
    if not results or not all(r.successful for r in results):
        run.notes.append(f'map_yaml not set: {results}')
    for step in (T.TRANSITION_CONFIGURE, T.TRANSITION_ACTIVATE):
        run.transition(step)
    run.mark('cleaned up, map_yaml set to the office, configured and activated')
    time.sleep(6.0)


SCENARIOS = {'map_republished': map_republished, 'localizer_late': localizer_late,
             'localizer_drops': localizer_drops, 'laser_late': laser_late,
             'laser_stops': lambda run: laser_stopped(run, signal.SIGTERM),
             'sim_killed': lambda run: laser_stopped(run, signal.SIGKILL),
             'lifecycle_mid_goal': lifecycle_mid_goal, 'lifecycle_by_id': lifecycle_by_id,
             'unprepared_method': unprepared_method, 'params_mid_goal': params_mid_goal,
             'client_killed': client_killed, 'stored_pose_unreadable': stored_pose_unreadable,
             'stored_pose_prior': stored_pose_prior, 'hostile_map': hostile_map}


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
