"""The one interface every matcher implements.

A matcher is built once per map (precomputation in __init__, reused for every scan)
and aligns one scan's points against that map. `match` returns candidate laser poses
in the map frame with scores, best first, where a higher score is better; it reports
progress through `progress(fraction, best_score)`, which may raise `Cancelled` to stop
the search early.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable, Optional

from ..map_io import OccupancyMap
from ..scan import ScanPoints
from ..transform import Rigid2D

ProgressFn = Callable[[float, float], None]


class Cancelled(Exception):
    """Raised from a progress callback to abandon a search."""


class MethodError(ValueError):
    """An unknown matcher name, or one this OpenCV build cannot provide."""


@dataclass
class Candidate:
    laser_pose: Rigid2D    # laser frame in the map frame
    score: float           # higher is better; scale depends on the matcher


@dataclass
class MatchOptions:
    """Per-request knobs that every matcher reads (those it does not need it ignores)."""
    angle_step_deg: float = 5.0
    opening_kernel: int = 3
    peaks_per_angle: int = 3


class Matcher(ABC):
    name: str = ''
    # Score at or above which a best candidate counts as a match, on this matcher's scale.
    min_score: float = 0.0

    def __init__(self, occupancy_map: OccupancyMap):
        self.map = occupancy_map

    @abstractmethod
    def match(self, points: ScanPoints, options: MatchOptions,
              progress: Optional[ProgressFn] = None) -> list[Candidate]:
        """Candidates for the laser pose, best first (possibly empty)."""
