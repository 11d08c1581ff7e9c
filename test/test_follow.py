"""Following an ambiguous answer's hypotheses with odometry, without ROS
(core.motion.HypothesisFollower): the pybullet simulator turns the robot in place and
gives its wheel odometry; twin aisle ends settle, a four-fold symmetric room does not,
and the fused view is searched by scan time, so the same observations give the same
answer however fast they come."""
import math

import pytest

from conftest import aisles_with_a_box, assert_pose_near, symmetric_room
from global_loc.bench.relocalization import turning_observations
from global_loc.core.localizer import Localizer
from global_loc.core.motion import SETTLE_PERIOD_S, HypothesisFollower
from global_loc.core.outcome import Outcome
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.simulator import BASE_T_LASER, Simulator

AISLE_END = (aisles_with_a_box, Rigid2D(4.0, 4.3, math.pi / 2), LaserConfig(fov_deg=180, num_beams=361, range_max=2.5))
SYMMETRIC = (symmetric_room, Rigid2D(2.0, 1.4, 0.4), LaserConfig(fov_deg=360, num_beams=720, range_max=20.0))


class CountingLocalizer(Localizer):
    """A real Localizer that counts the searches of a fused view (points, not beams)."""
    fused_searches = 0

    def localize_points(self, points, *args, **kwargs):
        self.fused_searches += not points.beams
        return super().localize_points(points, *args, **kwargs)


def turn_and_follow(world, seed=1):
    """(the single-scan result, the follow outcome, the true pose at the end, the localizer)."""
    make_map, start, laser = world
    m = make_map()
    sim, localizer = Simulator(m, laser, seed=seed), CountingLocalizer(m)
    try:
        sim.place(start)
        single = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
        assert single.outcome == Outcome.AMBIGUOUS and len(single.hypotheses) >= 2, single.message
        follower = HypothesisFollower(single, localizer, BASE_T_LASER, sim.odom, 100.0)
        follower.follow(turning_observations(sim, follower, 100.0))
        return single, follower.finish(), sim.true_pose(), localizer
    finally:
        sim.close()


def test_twin_aisle_ends_settle_on_the_true_place_while_turning():
    single, outcome, truth, localizer = turn_and_follow(AISLE_END)
    assert outcome.settled and outcome.result.outcome == Outcome.LOCALIZED, outcome.result.message
    assert outcome.result.message.startswith('localized by motion after')
    assert_pose_near(outcome.result.pose, truth, 0.1, 2.0)            # the robot's pose at the last scan used
    assert outcome.result.hypotheses[0].pose == outcome.result.pose
    assert 0.5 * math.pi < outcome.turned_rad < 2 * math.pi and outcome.travelled_m < 0.3
    assert outcome.last is not None and outcome.elapsed_s == pytest.approx(outcome.last.stamp - 100.0)
    assert outcome.scans == round(outcome.elapsed_s / 0.1)
    # one search of the fused view per second of scan time at most (and one when it settled)
    assert 1 <= localizer.fused_searches <= outcome.elapsed_s / SETTLE_PERIOD_S + 1


def test_a_symmetric_room_stays_ambiguous_after_a_full_turn():
    single, outcome, truth, _ = turn_and_follow(SYMMETRIC)
    assert not outcome.settled and outcome.result.outcome == Outcome.AMBIGUOUS
    assert outcome.result.message.startswith('ambiguous after') and '4 place(s) still match' in outcome.result.message
    assert len(outcome.result.hypotheses) == 4 and outcome.turned_rad >= 2 * math.pi
    # the hypotheses were followed: one of them is where the robot is now
    assert min(h.pose.distance_to(truth)[0] for h in outcome.result.hypotheses) < 0.1


def test_the_same_observations_give_the_same_outcome():
    """Time is the scans' stamps: a replay (offline, any speed) decides as the live run did."""
    make_map, start, laser = AISLE_END
    m = make_map()
    sim, localizer = Simulator(m, laser, seed=1), Localizer(m)
    try:
        sim.place(start)
        single = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
        recorder = HypothesisFollower(single, localizer, BASE_T_LASER, sim.odom, 0.0)
        start_odometry, recorded = sim.odom, []
        for obs in turning_observations(sim, recorder, 0.0):
            recorded.append(obs)
            if recorder.observe(obs):
                break
    finally:
        sim.close()
    replays = []
    for _ in range(2):
        follower = HypothesisFollower(single, localizer, BASE_T_LASER, start_odometry, 0.0)
        assert follower.follow(iter(recorded))
        replays.append(follower.finish())
    assert replays[0].result.pose == replays[1].result.pose and replays[0].scans == replays[1].scans == len(recorded)


def test_a_cancelled_follow_does_not_search_the_fused_view_again():
    make_map, start, laser = SYMMETRIC
    m = make_map()
    sim, localizer = Simulator(m, laser, seed=2), CountingLocalizer(m)
    try:
        sim.place(start)
        single = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
        follower = HypothesisFollower(single, localizer, BASE_T_LASER, sim.odom, 0.0)
        observations = turning_observations(sim, follower, 0.0)
        follower.follow(next(observations) for _ in range(5))
    finally:
        sim.close()
    searches = localizer.fused_searches
    outcome = follower.finish(search_fused=False)
    assert localizer.fused_searches == searches and not outcome.settled and outcome.scans == 5
