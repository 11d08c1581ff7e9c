"""The ROS-free parts of keeping a robot localized: the supervisor's states and guards,
odometry by stamp, and the motion resolver on ray-cast scans."""
import math
import threading

import numpy as np
import pytest

from conftest import assert_pose_near, symmetric_room
from global_loc.core.localizer import Localizer
from global_loc.core.motion import MotionResolver
from global_loc.core.outcome import CanceledError, Outcome
from global_loc.core.pose_history import PoseHistory
from global_loc.core.scan import scan_to_points
from global_loc.core.supervisor import Health, Supervisor, SupervisorConfig
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan

AUTO = SupervisorConfig(auto_relocalize=True, lost_after_s=3.0, min_interval_s=10.0, max_attempts=2, settle_s=5.0)


def test_low_fit_is_degraded_then_lost_after_the_window_and_recovers():
    s = Supervisor(AUTO, now=0.0)
    s.on_pose(0.0)
    assert s.on_fit(1.0, 0.9) == Health.LOCALIZED
    assert s.on_fit(2.0, 0.45) == Health.DEGRADED
    assert s.on_fit(3.0, 0.2) == Health.DEGRADED          # low, not yet for long
    assert s.on_fit(5.9, 0.2) == Health.DEGRADED
    assert s.on_fit(6.1, 0.2) == Health.LOST
    assert s.should_relocalize(6.1).startswith('lost: fit 0.20')
    assert s.on_fit(7.0, 0.85) == Health.LOCALIZED
    assert s.should_relocalize(7.0) is None


def test_relocalization_guards_interval_attempts_and_settling():
    s = Supervisor(AUTO, now=0.0)
    s.on_pose(0.0)
    for t in (1.0, 5.0):
        s.on_fit(t, 0.1)
    assert s.should_relocalize(5.0)
    s.started_relocalization(5.0)
    assert s.on_fit(5.5, 0.1) == Health.RELOCALIZING and s.should_relocalize(5.5) is None   # one at a time
    s.finished_relocalization(6.0, published=True, ambiguous=False)
    assert s.on_fit(8.0, 0.1) == Health.RELOCALIZING          # the localizer has settle_s to take the pose
    assert s.should_relocalize(8.0) is None
    assert s.on_fit(11.5, 0.1) == Health.LOST                 # it did not: lost again
    assert s.should_relocalize(12.0) is None                  # min_interval_s after the last attempt
    assert s.should_relocalize(15.1)
    s.started_relocalization(15.1)
    s.finished_relocalization(16.0, published=False, ambiguous=True)
    assert s.health == Health.AMBIGUOUS
    assert s.should_relocalize(40.0) is None and 'gave up after 2' in s.note     # max_attempts
    s.on_fit(41.0, 0.9)                                       # a pose from elsewhere fits: start over
    assert s.health == Health.LOCALIZED and s.attempts == 0


def test_without_any_pose_it_relocalizes_after_the_start_delay_and_never_when_off():
    s = Supervisor(AUTO, now=0.0)
    assert s.health == Health.UNKNOWN and s.should_relocalize(1.0) is None
    assert s.should_relocalize(2.5) == 'no pose from the localizer yet'
    off = Supervisor(SupervisorConfig(), now=0.0)             # auto_relocalize defaults to off
    off.on_pose(0.0)
    off.on_fit(0.0, 0.0)
    assert off.on_fit(10.0, 0.0) == Health.LOST and off.should_relocalize(10.0) is None


def test_a_published_pose_the_localizer_never_takes_is_retried_after_settle_s():
    """The localizer (AMCL) was not up when the one /initialpose went out: after settle_s
    without a pose from it the state is unknown again, and the guards let it retry."""
    s = Supervisor(AUTO, now=0.0)
    assert s.should_relocalize(2.5) == 'no pose from the localizer yet'
    s.started_relocalization(2.5)
    s.finished_relocalization(3.0, published=True, ambiguous=False)
    assert s.health == Health.RELOCALIZING and s.should_relocalize(7.9) is None     # settling
    assert s.should_relocalize(8.1) is None and s.health == Health.UNKNOWN        # expired; min_interval_s
    assert 'took no pose' in s.note
    assert s.should_relocalize(12.6) == 'no pose from the localizer yet'           # retried
    s.started_relocalization(12.6)
    s.finished_relocalization(13.0, published=True, ambiguous=False)
    s.on_pose(14.0)                                           # this time it took it
    assert s.should_relocalize(30.0) is None and s.health == Health.RELOCALIZING


def test_no_attempt_is_made_or_counted_before_a_scan_has_arrived():
    """A laser that starts 30 s late: no attempt before its first scan, and one that found
    no scan (the laser stopped) is not counted against max_attempts."""
    s = Supervisor(AUTO, now=0.0)
    for t in range(3, 30):
        assert s.should_relocalize(float(t), scan_arrived=False) is None
    assert s.attempts == 0 and s.health == Health.UNKNOWN
    assert s.should_relocalize(30.0, scan_arrived=True) == 'no pose from the localizer yet'
    s.started_relocalization(30.0)
    s.finished_relocalization(35.0, published=False, ambiguous=False, counted=False)   # NO_SCAN
    assert s.attempts == 0 and s.health == Health.UNKNOWN
    assert s.should_relocalize(35.1) == 'no pose from the localizer yet'


def test_pose_history_interpolates_and_gives_the_motion_between_stamps():
    h = PoseHistory(keep_s=5.0)
    assert h.at(1.0) is None
    for k in range(11):
        h.add(k * 0.1, Rigid2D(k * 0.1, 0.0, k * 0.1))
    assert h.at(0.25).as_tuple() == pytest.approx((0.25, 0.0, 0.25))
    assert h.at(-1.0).as_tuple() == pytest.approx((0.0, 0.0, 0.0)) and h.at(9.0).x == pytest.approx(1.0)
    motion = h.motion(0.2, 0.5)
    assert (Rigid2D(0.2, 0.0, 0.2) * motion).as_tuple() == pytest.approx((0.5, 0.0, 0.5))
    h.add(10.0, Rigid2D(7.0, 0.0, 0.0))                       # 9 s later: the old ones (> keep_s) go
    assert h.at(0.0).as_tuple() == pytest.approx((7.0, 0.0, 0.0))


def test_pose_history_waits_for_a_pose_still_on_its_way():
    """The odometry of a moment comes after the scan of it: a reader waits for it."""
    h = PoseHistory()
    h.add(1.0, Rigid2D(1.0, 0.0, 0.0))
    assert h.wait_until(1.0) and not h.wait_until(1.1, timeout_s=0.05)
    later = threading.Timer(0.1, h.add, (1.2, Rigid2D(1.2, 0.0, 0.0)))
    later.start()
    assert h.wait_until(1.1, timeout_s=5.0)
    assert h.at(1.1).x == pytest.approx(1.1)         # interpolated, not the pose held at 1.0
    with pytest.raises(CanceledError):
        h.wait_until(9.0, timeout_s=5.0, cancelled=lambda: True)
    assert not PoseHistory().wait_until(timeout_s=0.05)       # none at all


def test_motion_never_picks_one_of_perfect_twins():
    """A four-fold symmetric room, turning in place: every place keeps matching."""
    m = symmetric_room()
    truth = Rigid2D(2.0, 1.4, 0.4)
    rng = np.random.default_rng(2)
    laser = LaserConfig(360.0, 720, range_max=20.0, noise_std=0.01, dropout=0.01)
    localizer = Localizer(m)
    result = localizer.localize(simulate_scan(m, truth, laser, rng=rng))
    assert result.outcome == Outcome.AMBIGUOUS
    matcher = localizer.matcher('bnb')
    resolver = MotionResolver([h.pose for h in result.hypotheses])
    pose = truth
    for _ in range(60):
        step = Rigid2D(0.0, 0.0, 0.1)
        pose = pose * step
        points = scan_to_points(simulate_scan(m, pose, laser, rng=rng))

        def fit(base, points=points):
            score, through, refined = matcher.fit_at(points, base)
            return score * (1 - through), refined
        assert resolver.update(step, fit) is None
    assert len(resolver.tracks) == 4 and resolver.turned > math.pi
    assert any(t.pose.distance_to(pose)[0] < 0.1 for t in resolver.tracks)
    assert_pose_near(min(resolver.tracks, key=lambda t: t.pose.distance_to(pose)[0]).pose, pose, 0.1, 2.0)


def test_scans_of_the_way_fused_into_one_view_settle_what_one_scan_cannot():
    """Twin aisle ends: one 180 deg / 2.5 m look is ambiguous; the looks of one turn, fused
    with the odometry, are one place - and in a symmetric room they stay ambiguous."""
    from global_loc.core.motion import fuse_scans
    from global_loc.sim.synthetic_maps import aisles_with_a_box
    cases = [(aisles_with_a_box(), Rigid2D(4.0, 4.4, math.pi / 2),
              LaserConfig(180.0, 361, range_max=2.5, noise_std=0.005, dropout=0.0), Outcome.LOCALIZED),
             (symmetric_room(), Rigid2D(2.0, 1.4, 0.4),
              LaserConfig(360.0, 720, range_max=20.0, noise_std=0.005, dropout=0.0), Outcome.AMBIGUOUS)]
    for m, truth, laser, outcome in cases:
        rng = np.random.default_rng(1)
        localizer = Localizer(m)
        seen, pose = [], truth
        for _ in range(20):
            seen.append((pose, scan_to_points(simulate_scan(m, pose, laser, rng=rng))))
            pose = pose * Rigid2D(0.0, 0.0, 0.3)
        assert localizer.localize(simulate_scan(m, truth, laser, rng=rng)).outcome == \
            Outcome.AMBIGUOUS
        fused = localizer.localize_points(fuse_scans(seen), 'bnb')
        assert fused.outcome == outcome, fused.message
        if outcome == Outcome.LOCALIZED:
            assert_pose_near(fused.pose, seen[-1][0], 0.1, 2.0)
