"""Following an ambiguous answer's hypotheses with odometry, without ROS
(core.motion.HypothesisFollower): the pybullet simulator turns the robot in place and
gives its wheel odometry; twin aisle ends settle, a four-fold symmetric room does not,
and the fused view is searched by scan time, so the same observations give the same
answer however fast they come. Offline, `localize --follow` does the same on a bag written
here and on a shared CARMEN log."""
import dataclasses
import itertools
import json
import math
import os
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from test_bag import laser_scan

from conftest import SHARED_DATA, aisles_with_a_box, assert_pose_near, symmetric_room
from global_loc.bench.relocalization import turning_observations
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.map_io import save_map_yaml
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


@dataclass
class Turn:
    single: object               # the single scan's (ambiguous) result
    follower: HypothesisFollower
    used: list                   # the observations it was given
    start_odometry: Rigid2D
    truth: Rigid2D               # the true base pose at the end
    localizer: CountingLocalizer


def follow_a_turn(world, seed=1, max_scans=None, method='bnb') -> Turn:
    """One scan at the world's start (localized by `method`), then its hypotheses followed
    while the robot turns in place (one turn, or max_scans scans), until one settles."""
    make_map, start, laser = world
    m = make_map()
    sim, localizer = Simulator(m, laser, seed=seed), CountingLocalizer(m, LocalizerConfig(method=method))
    try:
        sim.place(start)
        single = localizer.localize(sim.scan(), base_T_laser=BASE_T_LASER)
        assert single.outcome == Outcome.AMBIGUOUS and len(single.hypotheses) >= 2, single.message
        turn = Turn(single, HypothesisFollower(single, localizer, BASE_T_LASER, sim.odom, 100.0), [], sim.odom,
                    start, localizer)
        for obs in itertools.islice(turning_observations(sim, turn.follower, 100.0), max_scans):
            turn.used.append(obs)
            if turn.follower.observe(obs):
                break
        turn.truth = sim.true_pose()
        return turn
    finally:
        sim.close()


@pytest.mark.parametrize('seed', [1, 15, 29])
def test_twin_aisle_ends_settle_on_the_true_place_while_turning(seed):
    """Seed 15: two hypotheses 1 m apart both slide onto the true place (one, merged), and
    the view fused over the whole turn leads the twin aisle by 4.8%, short of a single
    scan's 5%: the followed twin it ties with is one the leader outscored. Seed 29: the
    true place is not among the single scan's 8 hypotheses (a wrong one leads, and the
    fused view refuses it); the fused view's close places are taken up, replayed over the
    scans seen, and the true one wins."""
    turn = follow_a_turn(AISLE_END, seed)
    outcome = turn.follower.finish()
    assert outcome.settled and outcome.result.outcome == Outcome.LOCALIZED, outcome.result.message
    assert outcome.result.message.startswith('localized by motion after')
    assert_pose_near(outcome.result.pose, turn.truth, 0.1, 2.0)        # the robot's pose at the last scan used
    assert outcome.result.hypotheses[0].pose == outcome.result.pose
    assert 0.5 * math.pi < outcome.turned_rad < 2 * math.pi and outcome.travelled_m < 0.3
    assert outcome.last is turn.used[-1] and outcome.elapsed_s == pytest.approx(outcome.last.stamp - 100.0)
    assert outcome.scans == len(turn.used) == round(outcome.elapsed_s / 0.1)
    # one search of the fused view per second of scan time at most (and one when it settled)
    assert 1 <= turn.localizer.fused_searches <= outcome.elapsed_s / SETTLE_PERIOD_S + 1


@pytest.mark.parametrize('method', ['template_ccoeff', 'template_sqdiff'])
def test_a_thesis_matchers_ambiguous_answer_is_followed_and_settled_by_the_tracker(method):
    """The thesis matchers score no scan at a given pose (they are not Trackers): the
    follower of a server configured for one tracks with bnb, as Localizer.tracker says."""
    turn = follow_a_turn(AISLE_END, 1, method=method)
    assert turn.single.method == method and turn.follower.tracker.name == 'bnb'
    outcome = turn.follower.finish()
    assert outcome.settled and outcome.result.outcome == Outcome.LOCALIZED, outcome.result.message
    assert_pose_near(outcome.result.pose, turn.truth, 0.1, 2.0)


def test_a_symmetric_room_stays_ambiguous_after_a_full_turn():
    turn = follow_a_turn(SYMMETRIC)
    outcome = turn.follower.finish()
    assert not outcome.settled and outcome.result.outcome == Outcome.AMBIGUOUS
    assert outcome.result.message.startswith('ambiguous after') and '4 place(s) still match' in outcome.result.message
    # the scores are no longer the matcher's: the message says what they are
    assert f'scored by their mean fit over the {outcome.scans} scans followed' in outcome.result.message
    assert all(0.0 < h.score <= 1.0 for h in outcome.result.hypotheses)
    assert len(outcome.result.hypotheses) == 4 and outcome.turned_rad >= 2 * math.pi
    # the hypotheses were followed: one of them is where the robot is now
    assert min(h.pose.distance_to(turn.truth)[0] for h in outcome.result.hypotheses) < 0.1


def test_the_same_observations_give_the_same_outcome():
    """Time is the scans' stamps: a replay (offline, any speed) decides as the live run did."""
    turn = follow_a_turn(AISLE_END)
    live = turn.follower.finish()
    for _ in range(2):
        replay = HypothesisFollower(turn.single, turn.localizer, BASE_T_LASER, turn.start_odometry, 100.0)
        assert replay.follow(iter(turn.used))
        again = replay.finish()
        assert again.result.pose == live.result.pose and again.scans == live.scans == len(turn.used)


def test_a_cancelled_follow_does_not_search_the_fused_view_again():
    turn = follow_a_turn(SYMMETRIC, seed=2, max_scans=5)
    searches = turn.localizer.fused_searches
    outcome = turn.follower.finish(search_fused=False)
    assert turn.localizer.fused_searches == searches and not outcome.settled and outcome.scans == 5


# ---- offline: `python -m global_loc localize --bag B|--carmen LOG --follow` ------------------
TYPES = get_typestore(Stores.ROS2_JAZZY)


def stamp_msg(t: float):
    sec = int(t)
    return TYPES.types['builtin_interfaces/msg/Time'](sec=sec, nanosec=int(round((t - sec) * 1e9)))


def odometry_msg(pose: Rigid2D, t: float):
    m = TYPES.types
    header = m['std_msgs/msg/Header'](stamp=stamp_msg(t), frame_id='odom')
    q = m['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=math.sin(pose.yaw / 2), w=math.cos(pose.yaw / 2))
    p = m['geometry_msgs/msg/Pose'](position=m['geometry_msgs/msg/Point'](x=pose.x, y=pose.y, z=0.0), orientation=q)
    twist = m['geometry_msgs/msg/Twist'](linear=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
                                         angular=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0))
    return m['nav_msgs/msg/Odometry'](
        header=header, child_frame_id='base_link',
        pose=m['geometry_msgs/msg/PoseWithCovariance'](pose=p, covariance=np.zeros(36)),
        twist=m['geometry_msgs/msg/TwistWithCovariance'](twist=twist, covariance=np.zeros(36)))


def write_turning_bag(path, occupancy_map, start: Rigid2D, laser: LaserConfig, seconds: float) -> list[Rigid2D]:
    """A robot turning in place (pybullet, 0.4 rad/s): /scan at 10 Hz and /odom at 20 Hz. The
    laser is taken as the base (the odometry is the laser's pose by the wheels), as a bag
    read without a mounting is. Returns the true laser pose of each scan."""
    sim = Simulator(occupancy_map, laser, seed=1)
    truths, t0 = [], 100.0
    try:
        sim.place(start)
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            scans = writer.add_connection('/scan', 'sensor_msgs/msg/LaserScan', typestore=TYPES)
            odom = writer.add_connection('/odom', 'nav_msgs/msg/Odometry', typestore=TYPES)
            for k in range(int(seconds / 0.05)):
                t = t0 + 0.05 * k
                writer.write(odom, int(t * 1e9), TYPES.serialize_cdr(odometry_msg(sim.odom * BASE_T_LASER, t),
                                                                     'nav_msgs/msg/Odometry'))
                if k % 2 == 0:
                    msg = laser_scan(sim.scan(), 0)
                    msg.header.stamp = stamp_msg(t)
                    writer.write(scans, int(t * 1e9), TYPES.serialize_cdr(msg, 'sensor_msgs/msg/LaserScan'))
                    truths.append(sim.laser_pose())
                sim.drive(0.0, 0.4, 0.05)
    finally:
        sim.close()
    return truths


def run_follow(*args):
    out = subprocess.run([sys.executable, '-m', 'global_loc', 'localize', *args], capture_output=True, text=True,
                         timeout=300)
    return out, [json.loads(line) for line in out.stdout.splitlines()]


@pytest.mark.process
def test_follow_on_a_bag_settles_twin_aisle_ends_with_the_recorded_odometry(tmp_path):
    make_map, start, laser = AISLE_END
    save_map_yaml(make_map(), tmp_path / 'world.yaml')
    truths = write_turning_bag(tmp_path / 'run', make_map(), start, laser, 20.0)
    out, rows = run_follow('--map', str(tmp_path / 'world.yaml'), '--bag', str(tmp_path / 'run'), '--follow',
                           '--every', '150')
    assert out.returncode == 0, out.stderr
    assert [r['index'] for r in rows] == [0, 150]
    first = rows[0]
    assert first['single']['outcome'] == 'ambiguous' and first['single']['hypotheses'] >= 2, first
    assert first['followed'] and first['settled'] and first['outcome'] == 'localized', first
    assert 90 < first['turn_deg'] < 360 and first['scans'] == first['at_index']
    assert first['distance_m'] < BASE_T_LASER.x * math.radians(first['turn_deg']) + 0.1    # the laser's circle
    assert_pose_near(Rigid2D(first['x'], first['y'], first['yaw']), truths[first['at_index']], 0.1, 2.0)
    assert first['follow_s'] == pytest.approx(first['at_stamp'] - first['stamp'], abs=1e-6)
    assert first['time_s'] > 0 and first['message'].startswith('localized by motion')
    # the last start has 5 s of recording left: followed to the end or settled within it
    assert rows[1]['follow_s'] <= 5.0 and rows[1]['at_stamp'] <= 120.0
    short, rows = run_follow('--map', str(tmp_path / 'world.yaml'), '--bag', str(tmp_path / 'run'), '--follow',
                             '--every', '1000', '--follow-s', '1.5')
    assert short.returncode == 0 and rows[0]['follow_s'] <= 1.5 and rows[0]['scans'] <= 15, rows


@pytest.mark.process
def test_follow_without_odometry_in_the_bag_is_a_clear_error(tmp_path):
    make_map, start, laser = AISLE_END
    write_turning_bag(tmp_path / 'run', make_map(), start, laser, 1.0)
    out, _ = run_follow('--bag', str(tmp_path / 'run'), '--follow', '--odom-topic', '/wheel_odom')
    assert out.returncode == 2 and 'no nav_msgs/msg/Odometry on /wheel_odom (--odom-topic); the recording has: ' \
                                   '/odom (nav_msgs/msg/Odometry), /scan (sensor_msgs/msg/LaserScan)' in out.stderr
    out, _ = run_follow('--scans', '-', '--follow')
    assert out.returncode == 2 and '--follow needs a recording with odometry: --bag or --carmen' in out.stderr


ACES = os.path.join(SHARED_DATA, 'carmen', 'aces-corrected.log.gz')


@pytest.mark.process
@pytest.mark.skipif(not os.path.exists(ACES), reason=f'shared CARMEN logs not found ({ACES})')
def test_follow_on_a_carmen_log_settles_with_its_raw_odometry():
    """ACES (nearly four-fold symmetric): the ambiguous starts are followed over the next
    scans with the ODOM lines' raw odometry, and settle on the corrected pose."""
    out, rows = run_follow('--carmen', ACES, '--follow', '--every', '60')
    assert out.returncode == 0, out.stderr
    assert [r['index'] for r in rows] == list(range(0, 440, 60))
    followed = [r for r in rows if r['followed']]
    assert all(r['single']['outcome'] == 'ambiguous' for r in followed)
    assert all(not r['followed'] and r['outcome'] == r['single']['outcome'] for r in rows if r not in followed)
    settled = [r for r in followed if r['settled']]
    assert settled, followed
    for r in settled:
        assert r['outcome'] == 'localized' and r['at_index'] > r['index'] and r['distance_m'] > 0.5, r
        assert r['error_xy'] < 0.2 and r['error_yaw_deg'] < 5, r     # against the corrected pose of that scan


@pytest.mark.skipif(not os.path.exists(ACES), reason=f'shared CARMEN logs not found ({ACES})')
def test_follow_suite_rows_and_table_on_a_real_log():
    from global_loc.bench.follow import follow_section, log_rows
    rows = log_rows('aces', ACES, 6, 2015, 20.0)
    assert len(rows) == 6 and all(r['suite'] == 'follow' and r['log'] == 'aces' for r in rows)
    assert any(r['followed'] for r in rows)
    assert all(r['followed'] == (r['single_outcome'] == 'ambiguous') for r in rows)
    table = '\n'.join(follow_section(rows))
    assert '| aces | 6 |' in table


def test_a_follow_is_bounded_by_distance_and_scans_when_stamps_stop_advancing():
    """Stamps that stop advancing (a real log's wrap to one value) end no time window: the
    distance driven and the scan count bound it, and the bound that ended it is said."""
    from global_loc.core.scan import Scan
    from global_loc.offline.follow import FollowBounds, Frame, observations, stamps_not_advancing
    scan = Scan(-math.pi / 2, math.radians(1.0), 0.0, 8.0, np.full(181, 2.0), 0.0)
    frames = [Frame(i, dataclasses.replace(scan, stamp=min(i, 3) * 0.1), Rigid2D(0.1 * i, 0.0, 0.0),
                    where=f' (line {i + 1})') for i in range(400)]
    assert stamps_not_advancing(frames).startswith("the scans' stamps do not always advance (396 time(s)); first "
                                                   "at scan 4 (line 5): 0.300000 after 0.300000")
    ended = []
    seen = list(observations(frames, 0, FollowBounds.for_seconds(5.0), ended=ended))
    assert ended == ['distance'] and len(seen) == 50          # 5 m at 1 m/s, 0.1 m a scan
    ended = []
    seen = list(observations(frames, 0, FollowBounds(5.0, 100.0, 30), ended=ended))
    assert ended == ['scans'] and len(seen) == 30
    ended = []
    assert len(list(observations(frames, 0, FollowBounds(5.0, 100.0, 1000), ended=ended))) == 399 and ended == []
    assert stamps_not_advancing(frames[:4]) is None


@pytest.mark.process
@pytest.mark.skipif(not os.path.exists(ACES), reason=f'shared CARMEN logs not found ({ACES})')
def test_follow_on_a_log_whose_stamps_stop_advancing_warns_and_ends_by_distance(tmp_path):
    """ACES with every stamp after the 20th scan set to one value: before, a follow ran to the
    end of the log (hundreds of metres) and called that its window."""
    import gzip
    lines, scans = [], 0
    with gzip.open(ACES, 'rt') as f:
        for line in f.read().splitlines():
            if line.startswith('FLASER '):
                scans += 1
                if scans > 20:
                    parts = line.split()
                    parts[8 + int(parts[1])] = parts[-1] = '1000.0'      # ipc and logger timestamps
                    line = ' '.join(parts)
            lines.append(line)
    log = tmp_path / 'wrapped.log'
    log.write_text('\n'.join(lines) + '\n')
    out, rows = run_follow('--carmen', str(log), '--follow', '--every', '180', '--follow-s', '60')
    assert out.returncode == 0, out.stderr
    assert "warning: the scans' stamps do not always advance" in out.stderr and 'first at scan 21 (line 414)' in \
        out.stderr, out.stderr
    followed = [r for r in rows if r['followed']]
    assert followed, rows
    assert all(r['ended'] in ('settled', 'distance', 'scans') and r['distance_m'] <= 61.0 for r in followed), followed
