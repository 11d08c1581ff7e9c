"""The simulated 3D lidar: a 16-ring spinning lidar (Velodyne VLP-16's geometry: rings
every 2 deg over +-15 deg, 360 deg around), cast in the pybullet world by the simulator
(`Simulator.lidar_points`) from its mounting on the Pioneer (the URDF's lidar_joint:
sim/robot.py `LIDAR_MOUNT`, on a 0.2 m mast above the chassis over the wheel axle; the mast
and the laser below are not in its rays' way: the rays start at range_min, the chassis is
below -15 deg)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass
class Lidar3DConfig:
    rings: int = 16
    vertical_fov_deg: float = 30.0        # rings evenly from -15 to +15 deg
    columns: int = 450                    # azimuths per revolution (0.8 deg: 7200 rays, ~70 ms in pybullet)
    range_min: float = 0.3
    range_max: float = 30.0
    noise_std: float = 0.01               # Gaussian range noise, m
    rate_hz: float = 10.0

    def __post_init__(self):
        if self.rings < 1 or self.columns < 1 or not 0 <= self.range_min < self.range_max:
            raise ValueError(f'lidar needs rings >= 1, columns >= 1 and 0 <= range_min < range_max, got {self}')

    def elevations(self) -> np.ndarray:
        """Each ring's elevation (rad), lowest first."""
        half = math.radians(self.vertical_fov_deg) / 2.0
        return np.linspace(-half, half, self.rings) if self.rings > 1 else np.zeros(1)

    def directions(self) -> np.ndarray:
        """(rings, columns, 3) unit ray directions in the lidar frame, azimuth from -pi."""
        el = self.elevations()[:, None]
        az = (-math.pi + 2 * math.pi / self.columns * np.arange(self.columns))[None, :]
        return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)
