"""Settling an ambiguous place by motion, without ROS. The hypotheses of an ambiguous
answer are followed with odometry; each new scan is scored at each of them (refined
locally: cheap) and the evidence accumulates. Once the robot has moved far enough, the
first hypothesis whose mean fit leads the next by the margin a confident answer needs
wins; a view that never tells them apart (a perfectly symmetric room) never lets one win.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .transform import Rigid2D

# base pose -> (fit, refined base pose)
FitFn = Callable[[Rigid2D], tuple[float, Rigid2D]]


@dataclass(frozen=True)
class MotionConfig:
    lead: float = 0.05                   # relative lead of the mean fit a winner needs (bnb's confident margin)
    min_travel_m: float = 0.5            # ... after the robot drove this far
    min_turn: float = math.radians(90)   # ... or turned this much
    keep: float = 0.8                    # hypotheses whose mean fit falls below keep x the best are dropped


@dataclass
class Track:
    pose: Rigid2D                        # robot base in the map frame
    fits: list = field(default_factory=list)

    @property
    def evidence(self) -> float:
        return float(np.mean(self.fits)) if self.fits else 0.0


class MotionResolver:
    def __init__(self, hypotheses: list[Rigid2D], config: MotionConfig = MotionConfig()):
        self.config = config
        self.tracks = [Track(p) for p in hypotheses]
        self.travelled = 0.0
        self.turned = 0.0

    def update(self, motion: Rigid2D, fit: FitFn) -> Optional[Track]:
        """The robot moved by `motion` (base frame, from odometry) and a new scan came:
        move every hypothesis, score the scan there, drop the clearly worse; the winner,
        if one has emerged."""
        self.travelled += math.hypot(motion.x, motion.y)
        self.turned += abs(motion.yaw)
        for track in self.tracks:
            score, track.pose = fit(track.pose * motion)
            track.fits.append(score)
        self.tracks.sort(key=lambda t: -t.evidence)
        best = self.tracks[0].evidence
        self.tracks = [t for t in self.tracks if t.evidence >= self.config.keep * best]
        return self.winner()

    def winner(self) -> Optional[Track]:
        c = self.config
        if not self.tracks or (self.travelled < c.min_travel_m and self.turned < c.min_turn):
            return None
        best = self.tracks[0].evidence
        second = self.tracks[1].evidence if len(self.tracks) > 1 else 0.0
        return self.tracks[0] if best > 0 and best - second >= c.lead * best else None
