"""The simulated laser: its beam geometry and its faults, shared by the pybullet
simulator and the numpy ray caster so both make the same kind of scan."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LaserConfig:
    fov_deg: float = 270.0
    num_beams: int = 541
    range_min: float = 0.05
    range_max: float = 20.0
    noise_std: float = 0.01      # Gaussian range noise, m
    dropout: float = 0.01        # fraction of beams with no return (NaN)
    rate_hz: float = 10.0

    def angles(self) -> tuple[float, float, np.ndarray]:
        """(angle_min, angle_increment, angles) centred on the laser's x axis; a full
        circle has no duplicate beam at +180 deg."""
        fov = math.radians(self.fov_deg)
        if self.fov_deg >= 360.0:
            inc = fov / self.num_beams
            a0 = -math.pi
        else:
            inc = fov / (self.num_beams - 1)
            a0 = -fov / 2.0
        return a0, inc, a0 + inc * np.arange(self.num_beams)

    def corrupt(self, ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Ranges with Gaussian noise (noise_std) and NaN dropouts (dropout), in that order
        of random draws (the benchmark's seeded scans depend on it)."""
        if self.noise_std > 0:
            ranges = ranges + rng.normal(0.0, self.noise_std, ranges.shape)
        if self.dropout > 0:
            ranges[rng.random(ranges.shape) < self.dropout] = np.nan
        return ranges
