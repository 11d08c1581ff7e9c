"""The question the Python API asks (GlobalLocalizer.localize): one Localize goal's fields
(global_loc_interfaces/action/Localize.action) with Python types, each checked when the goal
is made - a field of the wrong type is a TypeError naming it before anything is sent (the
generated message conversion would abort the process, a C assertion, on say method=5).
0, '' and empty leave a field to the server's default, as in the action."""
from __future__ import annotations

import numbers as numbers_abc
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np
from geometry_msgs.msg import Pose2D

from global_loc_interfaces.action import Localize

from ..core.transform import Rigid2D


@dataclass(frozen=True)
class LocalizeGoal:
    method: Optional[str] = None          # a matcher name; None: the server's default
    angle_step_deg: float = 0.0           # the rotated-template matcher's step
    timeout_s: float = 0.0                # how long the server waits for a scan
    # The search prior, of the robot base in the map frame: within `radius_m` of `near` (a
    # Rigid2D or (x, y, yaw), radians; 0: the whole map) and `yaw_tolerance_deg` of its
    # heading (0: any heading).
    near: Any = None
    radius_m: float = 0.0
    yaw_tolerance_deg: float = 0.0
    resolve_by_motion_s: float = 0.0      # an ambiguous answer followed while the robot moves (0: not)
    rotate_in_place: bool = False         # ... with the server turning the robot once, slowly
    publish: bool = True                  # a confident pose goes on /initialpose
    publish_if_ambiguous: bool = False    # ... and the best hypothesis of an unsure one too
    maps: Sequence[str] = ()              # the maps to search in the server's map set (empty: every map)

    def __post_init__(self):
        check_goal_types(self)
        object.__setattr__(self, 'maps', tuple(self.maps))

    def to_msg(self) -> Localize.Goal:
        centre = self.near if isinstance(self.near, Rigid2D) else Rigid2D(*(self.near or (0.0, 0.0, 0.0)))
        return Localize.Goal(method=self.method or '', angle_step_deg=float(self.angle_step_deg),
                             timeout_s=float(self.timeout_s), publish_initialpose=bool(self.publish),
                             publish_if_ambiguous=bool(self.publish_if_ambiguous),
                             search_center=Pose2D(x=float(centre.x), y=float(centre.y), theta=float(centre.yaw)),
                             search_radius_m=float(self.radius_m),
                             search_yaw_tolerance_deg=float(self.yaw_tolerance_deg),
                             resolve_by_motion_s=float(self.resolve_by_motion_s),
                             rotate_in_place=bool(self.rotate_in_place), maps=list(self.maps))


NUMBERS = ('radius_m', 'yaw_tolerance_deg', 'resolve_by_motion_s', 'angle_step_deg', 'timeout_s')
FLAGS = ('rotate_in_place', 'publish', 'publish_if_ambiguous')


def _real(value) -> bool:
    return isinstance(value, numbers_abc.Real) and not isinstance(value, bool)


def check_goal_types(goal: LocalizeGoal) -> None:
    """TypeError naming the first field of the wrong type."""
    if goal.method is not None and not isinstance(goal.method, str):
        raise TypeError(f'method must be a str (a matcher name) or None, got {type(goal.method).__name__}')
    near = goal.near
    if near is not None and not isinstance(near, Rigid2D):
        if isinstance(near, (str, bytes)) or not hasattr(near, '__len__') or len(near) != 3 or \
                not all(map(_real, near)):
            raise TypeError(f'near must be a Rigid2D or (x, y, yaw) numbers, got {near!r}')
    for name in NUMBERS:
        if not _real(getattr(goal, name)):
            raise TypeError(f'{name} must be a number, got {type(getattr(goal, name)).__name__}')
    for name in FLAGS:
        if not isinstance(getattr(goal, name), (bool, np.bool_)):
            raise TypeError(f'{name} must be a bool, got {type(getattr(goal, name)).__name__}')
    maps = goal.maps
    if isinstance(maps, (str, bytes)) or not all(isinstance(m, str) for m in maps):
        raise TypeError(f'maps must be a sequence of map names (str), got {maps!r}')
