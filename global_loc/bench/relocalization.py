"""The `relocalization` suite: what keeping a robot localized without a person costs and
gains, in the pybullet simulator with its wheel odometry (no ROS; the same core pieces
the server runs: Localizer, MotionResolver, Supervisor).

- Kidnap and turn: the robot is put at a seeded free pose; one scan is localized; when
  the answer is ambiguous the robot turns in place (0.4 rad/s, one turn at most) and the
  hypotheses are followed with odometry until one wins (else the turn's scans, fused into
  one view, are searched again): core.motion.HypothesisFollower, the server's loop. Single-scan vs resolved success,
  confident-but-wrong for both, the angle turned until confident.
- Watch: the robot circles in the map's most open spot with the localizer's pose correct
  (the truth): lost alarms per hour. Then it is kidnapped while the believed pose stays
  at the old place: the time (simulated) until a confident pose is published.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..core.localizer import Localizer
from ..core.motion import HypothesisFollower, Observation, pose_fitter
from ..core.outcome import Outcome
from ..core.scan import scan_to_points
from ..core.supervisor import Health, Supervisor, SupervisorConfig
from ..core.transform import Rigid2D, pose_correct
from ..sim.raycast import sample_free_poses
from ..sim.simulator import BASE_T_LASER, Simulator

TICK = 0.1            # s: the simulator's scan period
TURN_RATE = 0.4       # rad/s, the server's default rotate_speed
HEALTH_PERIOD = 0.5   # s


def turning_observations(sim, follower: HypothesisFollower, t0: float):
    """Scans of a turn in place, one per tick, with the wheel odometry at each: until the
    odometry says one full turn (as the server's rotate-in-place; a stuck robot: 1.5 x
    the ticks a turn takes)."""
    for k in range(1, int(1.5 * 2 * math.pi / TURN_RATE / TICK)):
        if follower.turned >= 2 * math.pi:
            return
        sim.drive(0.0, TURN_RATE, TICK)
        yield Observation(scan_to_points(sim.scan()), sim.odom, t0 + k * TICK)


def kidnap_and_turn(name, m, localizer, sim, pose) -> dict:
    sim.place(pose)
    result = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
    row = {'suite': 'relocalization', 'test': 'kidnap_turn', 'map': name, 'single_outcome': result.outcome.label,
           'single_ok': bool(result.pose is not None and pose_correct(result.pose, sim.true_pose())),
           'single_success': result.success, 'turned_deg': 0.0}
    row['resolved_success'], row['resolved_ok'] = row['single_success'], row['single_ok']
    if result.outcome != Outcome.AMBIGUOUS:
        return row
    follower = HypothesisFollower(result, localizer, BASE_T_LASER, sim.odom, 0.0)   # the server's loop
    follower.follow(turning_observations(sim, follower, 0.0))
    sim.drive(0.0, 0.0, TICK)
    outcome = follower.finish()
    pose = outcome.result.pose if outcome.settled else None
    row.update(turned_deg=round(math.degrees(outcome.turned_rad), 1), resolved_success=pose is not None,
               resolved_ok=bool(pose is not None and pose_correct(pose, sim.true_pose())))
    return row


def open_spot(m):
    """The free cell farthest from anything not free, and that distance (m)."""
    d = cv2.distanceTransform(m.free.astype(np.uint8), cv2.DIST_L2, 5) * m.resolution
    r, c = np.unravel_index(int(np.argmax(d)), d.shape)
    return m.frame.pixel_to_world([[c, r]])[0], float(d[r, c])


def watch(name, m, localizer, sim, minutes: float, rng) -> list[dict]:
    """Circling with a correct pose (false alarms), then a kidnap (time to a published pose)."""
    (cx, cy), clearance = open_spot(m)
    radius = min(1.0, max(0.3, clearance - 0.6))
    sim.place(Rigid2D(cx, cy - radius, 0.0))
    matcher = localizer.tracker()
    config = SupervisorConfig(auto_relocalize=True)
    sup = Supervisor(config, now=0.0)
    sup.on_pose(0.0)
    alarms, t, steps = 0, 0.0, int(minutes * 60 / TICK)
    for k in range(steps):
        sim.drive(0.24, 0.24 / radius, TICK)
        t += TICK
        if k % int(HEALTH_PERIOD / TICK) == 0:
            fit, _ = pose_fitter(matcher, scan_to_points(sim.scan()), BASE_T_LASER)(sim.true_pose())
            before = sup.health
            if sup.on_fit(t, fit) == Health.LOST and before != Health.LOST:
                alarms += 1
    rows = [{'suite': 'relocalization', 'test': 'false_alarms', 'map': name, 'minutes': minutes, 'alarms': alarms}]
    # the kidnap: the believed pose stays where it was, moved by the odometry
    believed, odom_then = sim.true_pose(), sim.odom
    target = sample_free_poses(m, 1, rng, clearance=0.5)[0]
    sim.place(target)
    t0 = t
    published = None
    while t - t0 < 30.0 and published is None:
        sim.drive(0.0, 0.0, TICK)
        t += TICK
        believed_now = believed * (odom_then.inverse() * sim.odom)
        fit, _ = pose_fitter(matcher, scan_to_points(sim.scan()), BASE_T_LASER)(believed_now)
        sup.on_fit(t, fit)
        if sup.should_relocalize(t):
            sup.started_relocalization(t)
            result = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
            t += result.time_s            # the search's own time, in simulated time too
            sup.finished_relocalization(t, published=result.success, ambiguous=result.outcome == Outcome.AMBIGUOUS)
            if result.success:
                published = result
    rows.append({'suite': 'relocalization', 'test': 'kidnap_watch', 'map': name,
                 'published': published is not None,
                 'ok': bool(published is not None and pose_correct(published.pose, sim.true_pose())),
                 'seconds_to_pose': round(t - t0, 2) if published is not None else None})
    return rows


def fit_row(source: str, matcher, m, points, truth_laser: Rigid2D, rng) -> dict:
    """The fit at the true laser pose and at a random free pose (the supervisor's thresholds)."""
    def fit(laser):      # the laser pose itself: a base with the laser at its origin
        return round(pose_fitter(matcher, points, Rigid2D())(laser)[0], 4)
    return {'suite': 'relocalization', 'test': 'fit', 'source': source, 'true_fit': fit(truth_laser),
            'random_fit': fit(sample_free_poses(m, 1, rng)[0])}


def relocalization_rows(maps: dict, poses_per_map: int, watch_minutes: float, seed: int,
                        carmen_trials=(), carmen_maps=None) -> list[dict]:
    """Every row of the suite: kidnap-and-turn and watch per map, fits at true and random poses."""
    rows = []
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + 300 + i)
        localizer = Localizer(m)
        sim = Simulator(m, seed=seed + i)
        try:
            for pose in sample_free_poses(m, poses_per_map, rng, clearance=0.5):
                rows.append(kidnap_and_turn(name, m, localizer, sim, pose))
                rows.append(fit_row('sim', localizer.tracker(), m, scan_to_points(sim.scan()),
                                    sim.laser_pose(), rng))
            rows += watch(name, m, localizer, sim, watch_minutes, rng)
        finally:
            sim.close()
    rng = np.random.default_rng(seed + 400)
    localizers = {}
    for t in carmen_trials:
        m = carmen_maps[t.map_name]
        loc = localizers.setdefault(t.map_name, Localizer(m))
        rows.append(fit_row('carmen', loc.tracker(), m, scan_to_points(t.scan), t.truth, rng))
    return rows
