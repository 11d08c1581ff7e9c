"""A search prior: where the robot may be (a disc around a pose) and which way it may
face (a window around that pose's heading). A user who knows the robot is "in this
room" or "facing roughly north" excludes the rest of the map, which both settles
ambiguities the scan alone cannot and shrinks the search.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .transform import Rigid2D, normalize_angle


@dataclass(frozen=True)
class SearchRegion:
    center: Rigid2D
    radius_m: float = 0.0          # 0: anywhere on the map
    yaw_tolerance: float = 0.0     # rad; 0: any heading

    def __post_init__(self):
        values = (*self.center.as_tuple(), self.radius_m, self.yaw_tolerance)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f'search region values must be finite, got {values}')
        if self.radius_m < 0 or self.yaw_tolerance < 0:
            raise ValueError(f'search radius and yaw tolerance must be >= 0, got {self.radius_m}, '
                             f'{self.yaw_tolerance}')

    @property
    def bounded(self) -> bool:
        """Whether the region excludes anything."""
        return self.radius_m > 0 or 0 < self.yaw_tolerance < math.pi

    def contains(self, pose: Rigid2D) -> bool:
        if self.radius_m > 0 and math.hypot(pose.x - self.center.x, pose.y - self.center.y) > self.radius_m:
            return False
        return not (0 < self.yaw_tolerance and abs(normalize_angle(pose.yaw - self.center.yaw)) > self.yaw_tolerance)

    def widened_to(self, radius_m: float, yaw_tolerance: float) -> tuple['SearchRegion', str]:
        """This region with its disc and heading window at least `radius_m` and
        `yaw_tolerance` (rad) - a search's resolution: a tighter prior holds no pose that
        search can return, even centred on the truth - and what was widened, said ('' when
        nothing was). An unbounded radius or heading stays unbounded."""
        radius, tolerance, said = self.radius_m, self.yaw_tolerance, []
        if 0 < radius < radius_m:
            said.append(f'search radius {radius:.3g} m widened to {radius_m:.3g} m')
            radius = radius_m
        if 0 < tolerance < min(yaw_tolerance, math.pi):
            said.append(f'yaw tolerance {math.degrees(tolerance):.3g} deg widened to '
                        f'{math.degrees(yaw_tolerance):.3g} deg')
            tolerance = yaw_tolerance
        if not said:
            return self, ''
        said = ' and '.join(said) + ", the search's resolution, for the search; the answer lies in the prior"
        return SearchRegion(self.center, radius, tolerance), said

    def widened_by(self, metres: float, radians: float) -> 'SearchRegion':
        """This region with `metres` more radius and `radians` more heading window (each
        only where it is bounded)."""
        radius = self.radius_m + metres if self.radius_m > 0 else 0.0
        tolerance = min(self.yaw_tolerance + radians, math.pi) if 0 < self.yaw_tolerance < math.pi else \
            self.yaw_tolerance
        return SearchRegion(self.center, radius, tolerance)

    def nearest(self, pose: Rigid2D) -> Rigid2D:
        """The pose of this region nearest `pose`: its position moved onto the disc, its
        heading into the window (`pose` itself when the region contains it)."""
        if self.contains(pose):
            return pose
        x, y, yaw = pose.x, pose.y, pose.yaw
        dx, dy = x - self.center.x, y - self.center.y
        distance = math.hypot(dx, dy)
        inside = 1.0 - 1e-9     # onto the edge, and not past it by a rounding
        if 0 < self.radius_m < distance:
            x, y = (self.center.x + dx * inside * self.radius_m / distance,
                    self.center.y + dy * inside * self.radius_m / distance)
        off = normalize_angle(yaw - self.center.yaw)
        if 0 < self.yaw_tolerance < abs(off):
            yaw = normalize_angle(self.center.yaw + math.copysign(inside * self.yaw_tolerance, off))
        return Rigid2D(x, y, yaw)

    def for_laser(self, base_T_laser: Rigid2D) -> 'SearchRegion':
        """The region the laser lies in when the base lies in this one: the disc widened
        by the laser's offset (the base's heading turns it), the heading window turned by
        the laser's mounting yaw."""
        offset = math.hypot(base_T_laser.x, base_T_laser.y)
        return SearchRegion(Rigid2D(self.center.x, self.center.y, self.center.yaw + base_T_laser.yaw),
                            self.radius_m + offset if self.radius_m > 0 else 0.0, self.yaw_tolerance)
