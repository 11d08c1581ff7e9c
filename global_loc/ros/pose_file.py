"""The server's stored-pose file (`stored_pose_file`): each confident answer it publishes is
kept there, with the odometry at its scan; at activation and on
~/localize_from_stored_pose the request path tries it first (core/stored_pose.py). A file
that cannot be written or read is logged and the work goes on: a start-up without it is
a full search."""
from __future__ import annotations

import time

from ..core.pose_history import PoseHistory
from ..core.stored_pose import (
    SinceStored,
    StoredPoseError,
    confirm_stored_pose,
    load_stored_pose,
    save_stored_pose,
    stored_from_result,
)


class PoseFile:
    def __init__(self, path: str, odometry: PoseHistory, logger):
        self.path, self.odometry, self.logger = path, odometry, logger

    def save(self, result, scan_stamp: float, maps) -> None:
        """Keep a confident answer (`maps`: the maps it was searched among)."""
        try:
            save_stored_pose(self.path, stored_from_result(result, maps, time.time(), self.odometry.at(scan_stamp)))
        except (OSError, StoredPoseError) as e:
            self.logger.warn(f'the pose was not stored in {self.path}: {e}', throttle_duration_sec=10.0)

    def confirm(self, map_set, points, base_T_laser, scan_stamp: float, max_age_s: float) -> tuple:
        """(the confirmed answer, '') or (None, why not): core.stored_pose.confirm_stored_pose
        on the file's pose, with the odometry at the scan."""
        try:
            stored = load_stored_pose(self.path)
        except StoredPoseError as e:
            return None, str(e)
        since = SinceStored(time.time() - stored.stamp, self.odometry.at(scan_stamp))
        return confirm_stored_pose(map_set, points, stored, base_T_laser, since, max_age_s)
