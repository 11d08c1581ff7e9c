"""The health watch without a node: its collaborators are plain callables and a PoseHistory,
so its states, its throttle-free decisions and what it publishes are tested directly."""
import pytest
from builtin_interfaces.msg import Time
from sensor_msgs.msg import LaserScan

from global_loc.core.outcome import Outcome
from global_loc.core.pose_history import PoseHistory
from global_loc.core.supervisor import SupervisorConfig
from global_loc.core.transform import Rigid2D
from global_loc.ros.convert import pose_with_covariance
from global_loc.ros.watch import HealthWatch, WatchOutputs

pytestmark = pytest.mark.ros     # ROS message types (no node, no process)


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class Logger:
    def __init__(self):
        self.lines = []

    def warn(self, text, **kwargs):
        self.lines.append(text)


def make_watch(fits, **config):
    clock, logger, statuses, odometry = Clock(), Logger(), [], PoseHistory()
    odometry.add(0.0, Rigid2D())
    watch = HealthWatch(SupervisorConfig(**config), 'map', lambda msg, pose: fits.pop(0), odometry,
                        WatchOutputs(lambda msg: statuses.append(msg.data), lambda array: None, lambda: Time(), logger,
                                     'test'), clock=clock)
    return watch, clock, statuses, logger


def scan(stamp_s=0.0):
    msg = LaserScan()
    msg.header.stamp.sec = int(stamp_s)
    return msg


def pose_msg(frame='map', stamp_s=1.0):
    return pose_with_covariance(Rigid2D(1.0, 2.0, 0.0), [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], frame,
                                Time(sec=int(stamp_s)))


def test_lost_is_published_before_the_relocalization_it_starts():
    watch, clock, statuses, _ = make_watch([0.1] * 10, auto_relocalize=True, lost_after_s=1.0)
    watch.on_pose(pose_msg())
    reasons = []
    for t in (0.0, 0.5, 1.2):
        clock.t = t
        reasons.append(watch.tick(scan(t)))
    assert reasons[:2] == [None, None] and reasons[2].startswith('lost')
    assert [s.split()[0] for s in statuses[-3:]] == ['degraded', 'lost', 'relocalizing'], statuses
    watch.finished(Outcome.NO_SCAN, published=False)          # not an attempt: no scan reached it
    assert watch.supervisor.attempts == 0


def test_a_pose_in_another_frame_is_ignored_and_said():
    watch, clock, statuses, logger = make_watch([0.9] * 5)
    watch.on_pose(pose_msg(frame='odom'))
    assert watch.believed_pose(1.0) is None and 'frame "odom"' in logger.lines[0]
    watch.on_pose(pose_msg(frame='map'))
    assert watch.believed_pose(1.0) == Rigid2D(1.0, 2.0, 0.0)


def test_no_relocalization_before_the_first_scan():
    watch, clock, statuses, _ = make_watch([], auto_relocalize=True, start_delay_s=0.0)
    for t in range(5):
        clock.t = float(t)
        assert watch.tick(None) is None
    assert watch.tick(scan()) == 'no pose from the localizer yet'


def test_a_pose_stamped_zero_is_taken_as_of_the_newest_odometry():
    watch, clock, statuses, logger = make_watch([])
    watch.odometry.add(30.0, Rigid2D(5.0, 0.0, 0.0))          # the robot drove 5 m by 30 s
    watch.on_pose(pose_msg(stamp_s=0.0))
    assert watch.believed_pose(30.0) == Rigid2D(1.0, 2.0, 0.0)  # no 30 s of odometry applied
    assert 'stamped 0' in logger.lines[0]

