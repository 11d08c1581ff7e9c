"""LocalizeResult: one Localize goal's answer as the Python API (ros/api.py) returns it,
typed - and the client's JSON object (`test_global_loc --json`)."""
from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Optional

import numpy as np
from action_msgs.msg import GoalStatus

from global_loc_interfaces.action import Localize

from ..core.outcome import Outcome
from ..core.transform import Rigid2D
from .convert import pose_from_msg, stamp_seconds

STATUS_NAMES = {GoalStatus.STATUS_SUCCEEDED: 'succeeded', GoalStatus.STATUS_ABORTED: 'aborted',
                GoalStatus.STATUS_CANCELED: 'canceled'}


@dataclasses.dataclass(frozen=True)
class LocalizeResult:
    """The server's answer to one goal (global_loc_interfaces/action/Localize's result)."""
    outcome: Outcome
    success: bool                  # True only when the server is confident the pose is right
    message: str
    pose: Optional[Rigid2D]        # the robot base in `frame_id`; None when the server has no hypothesis
    covariance: Optional[np.ndarray]    # 3x3 (x, y, yaw), with `pose`
    score: float
    confidence: float
    hypotheses: list               # [(Rigid2D, score)], best first; hypotheses[0][0] is `pose` (scores: see
                                   # the action's hypothesis_scores - mean fits after resolving by motion)
    scan_stamp: float              # the localized scan's stamp, s (0 when no scan was used)
    scan_age_s: float
    elapsed_s: float
    status: str                    # how the action ended: succeeded | aborted | canceled
    frame_id: str = 'map'
    map: str = ''                  # the map `pose` is on (the server's map set names it)
    hypothesis_maps: tuple = ()    # the map of each hypothesis

    @staticmethod
    def from_msg(result: Localize.Result, status: int) -> 'LocalizeResult':
        hypotheses = [(pose_from_msg(p), float(s))
                      for p, s in zip(result.hypotheses.poses, result.hypothesis_scores, strict=True)]
        pose = covariance = None
        if hypotheses:
            pose = pose_from_msg(result.pose.pose.pose)
            covariance = np.asarray(result.pose.pose.covariance, dtype=float).reshape(6, 6)[np.ix_([0, 1, 5],
                                                                                                  [0, 1, 5])]
        try:
            outcome = Outcome(result.outcome)
        except ValueError:      # a newer server's outcome: no pose of it can be trusted here
            outcome = Outcome.NONE
        return LocalizeResult(outcome, bool(result.success), result.message, pose, covariance, float(result.score),
                              float(result.confidence), hypotheses, stamp_seconds(result.scan_stamp),
                              float(result.scan_age_s), float(result.elapsed_s),
                              STATUS_NAMES.get(status, str(status)), result.pose.header.frame_id or 'map',
                              result.map, tuple(result.hypothesis_maps))

    def padded_maps(self):
        """Each hypothesis's map, '' past the end (an older server sends none)."""
        return itertools.chain(self.hypothesis_maps, itertools.repeat(''))

    def as_dict(self) -> dict:
        """The client's JSON object (test_global_loc --json)."""
        return {'outcome': self.outcome.label, 'status': self.status, 'success': self.success,
                'message': self.message, 'score': self.score if math.isfinite(self.score) else None,
                'confidence': self.confidence, 'elapsed_s': self.elapsed_s, 'map': self.map,
                'hypotheses': [{**p.as_dict(), 'score': round(s, 5), **({'map': m} if m else {})}
                               for (p, s), m in zip(self.hypotheses, self.padded_maps(), strict=False)],
                'scan_stamp': self.scan_stamp, 'scan_age_s': self.scan_age_s,
                'pose': None if self.pose is None else self.pose.as_dict(),
                'covariance': None if self.covariance is None else self.covariance.tolist()}


class GlobalLocError(Exception):
    """The server gave no answer; `label` is the client's JSON `outcome` for it."""
    label = 'error'


class NoServer(GlobalLocError):
    """No global_loc server (action or service) answered within the timeout."""
    label = 'no_server'


class ServerGone(GlobalLocError):
    """The server left the ROS graph while a request waited for its answer (it crashed or stopped)."""
    label = 'server_gone'


class GoalUnanswered(GlobalLocError):
    """The server did not answer the goal request in time, nor ~/get_state (so it was not sent
    again): it is still starting, or stopping; wait_until_active, then ask again."""
    label = 'goal_unanswered'


class GoalRejected(GlobalLocError):
    """The server rejected the goal."""
    label = 'goal_rejected'
