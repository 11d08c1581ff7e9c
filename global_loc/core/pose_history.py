"""The recent poses of a moving frame (odometry), looked up at any stamp: the motion
between two moments - the localizer's pose and a scan, two scans - is then the motion
between exactly those moments, not between whenever the messages happened to arrive.
A reader can wait for the poses still on their way (`wait_until`): a robot publishes the
odometry of a moment after the scan of it, or on another topic that arrives later."""
from __future__ import annotations

import bisect
import math
import threading
import time
from typing import Callable, Optional

from .newest_message import wait_on
from .transform import Rigid2D, normalize_angle


class PoseHistory:
    def __init__(self, keep_s: float = 30.0):
        self.keep_s = keep_s
        self._stamps: list[float] = []
        self._poses: list[Rigid2D] = []
        self._lock = threading.Condition()

    def add(self, stamp: float, pose: Rigid2D) -> None:
        """A pose at `stamp` (seconds); older than keep_s behind the newest are forgotten."""
        with self._lock:
            if self._stamps and stamp < self._stamps[-1]:     # out of order (a restarted clock): start over
                self._stamps, self._poses = [], []
            self._stamps.append(stamp)
            self._poses.append(pose)
            cut = bisect.bisect_left(self._stamps, stamp - self.keep_s)
            del self._stamps[:cut], self._poses[:cut]
            self._lock.notify_all()

    def wait_until(self, stamp: float = -math.inf, timeout_s: float = 0.0,
                   cancelled: Callable[[], bool] = lambda: False, poll_s: float = 0.05) -> bool:
        """Whether the history reaches `stamp` (its newest pose is at or after it; the default:
        holds any pose), waiting up to `timeout_s` for it; raises CanceledError as soon as
        `cancelled()` says so."""
        with self._lock:
            return wait_on(self._lock, lambda: bool(self._stamps) and self._stamps[-1] >= stamp,
                           time.monotonic() + timeout_s, cancelled, poll_s=poll_s)

    def newest_stamp(self) -> Optional[float]:
        """The stamp of the newest pose, None when empty."""
        with self._lock:
            return self._stamps[-1] if self._stamps else None

    def at(self, stamp: float) -> Optional[Rigid2D]:
        """The pose at `stamp`, interpolated; the first or last one outside the history; None when empty."""
        with self._lock:
            if not self._stamps:
                return None
            i = bisect.bisect_left(self._stamps, stamp)
            if i == 0:
                return self._poses[0]
            if i == len(self._stamps):
                return self._poses[-1]
            t0, t1 = self._stamps[i - 1], self._stamps[i]
            a, b = self._poses[i - 1], self._poses[i]
        w = (stamp - t0) / (t1 - t0) if t1 > t0 else 1.0
        yaw = normalize_angle(a.yaw + w * normalize_angle(b.yaw - a.yaw))
        return Rigid2D(a.x + w * (b.x - a.x), a.y + w * (b.y - a.y), yaw)

    def motion(self, since: float, until: float) -> Optional[Rigid2D]:
        """How the frame moved (in its own frame at `since`) from `since` to `until`."""
        a, b = self.at(since), self.at(until)
        return None if a is None or b is None else a.inverse() * b
