"""GridFrame: the one owner of cell geometry - where a grid's cells are in the world.

A grid (a map, a scan's local map) is an image of `height` rows x `width` columns of
square cells `resolution` metres wide, placed in the world by `origin`, the pose of its
lower-left corner (nav2_map_server / nav_msgs/OccupancyGrid convention). Three frames:

- pixel (u, v): continuous image coordinates as OpenCV has them; cell (col, row) has its
  centre at (u, v) = (col, row); row 0 is the *top* row, so v grows downwards.
- grid (metres): x along the columns, y up along the rows, from the lower-left corner.
- world: `origin * grid`.

Everything that turns points, poses or covariances from one of these into another
calls this class (as Cartographer's MapLimits is the one place a point becomes a cell);
the compiled bnb kernels, which cannot call it, share one inline `image_point`
(core/pixel_kernels.py) for the same "v grows downwards" rule.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .transform import Rigid2D


@dataclass(frozen=True)
class GridFrame:
    resolution: float      # metres per cell
    width: int             # columns
    height: int            # rows
    origin: Rigid2D = Rigid2D()   # world_T_grid: pose of the lower-left corner

    # ---- points ------------------------------------------------------------------------
    def pixel_to_grid(self, uv) -> np.ndarray:
        """(N, 2) continuous pixel coordinates -> (N, 2) grid-frame metres."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        return np.stack([(uv[:, 0] + 0.5) * self.resolution,
                         (self.height - uv[:, 1] - 0.5) * self.resolution], axis=1)

    def grid_to_pixel(self, xy) -> np.ndarray:
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.stack([xy[:, 0] / self.resolution - 0.5,
                         self.height - xy[:, 1] / self.resolution - 0.5], axis=1)

    def pixel_to_world(self, uv) -> np.ndarray:
        return self.origin.apply(self.pixel_to_grid(uv))

    def world_to_pixel(self, xy) -> np.ndarray:
        return self.grid_to_pixel(self.origin.inverse().apply(xy))

    def cell_of(self, xy) -> np.ndarray:
        """(N, 2) integer (col, row) of the cells holding world points (possibly outside
        the grid: see `contains`)."""
        g = self.origin.inverse().apply(xy)
        col = np.floor(g[:, 0] / self.resolution).astype(int)
        row = self.height - 1 - np.floor(g[:, 1] / self.resolution).astype(int)
        return np.stack([col, row], axis=1)

    def contains(self, cells) -> np.ndarray:
        """Which (col, row) cells lie inside the grid."""
        cells = np.asarray(cells).reshape(-1, 2)
        return (cells[:, 0] >= 0) & (cells[:, 0] < self.width) & (cells[:, 1] >= 0) & (cells[:, 1] < self.height)

    def pixel_steps_to_grid(self, du, dv) -> tuple[np.ndarray, np.ndarray]:
        """Pixel displacements -> grid-frame displacements in metres (v points down)."""
        return np.asarray(du) * self.resolution, -np.asarray(dv) * self.resolution

    # ---- poses and covariances -----------------------------------------------------------
    def pixel_pose_to_world(self, u: float, v: float, yaw: float) -> Rigid2D:
        """A pose at continuous pixel (u, v) with grid-frame heading `yaw` -> world frame."""
        gx, gy = self.pixel_to_grid([[u, v]])[0]
        return self.origin * Rigid2D(float(gx), float(gy), yaw)

    def world_pose_to_pixel(self, pose: Rigid2D) -> tuple[float, float, float]:
        """(u, v, grid-frame heading) of a world pose."""
        g = self.origin.inverse() * pose
        u, v = self.grid_to_pixel([[g.x, g.y]])[0]
        return float(u), float(v), g.yaw

    def covariance_to_world(self, covariance) -> np.ndarray:
        """An (x, y, yaw) covariance in the grid frame -> the world frame."""
        rot = np.eye(3)
        c, s = math.cos(self.origin.yaw), math.sin(self.origin.yaw)
        rot[:2, :2] = [[c, -s], [s, c]]
        return rot @ np.asarray(covariance, dtype=float) @ rot.T

    def pixel_to_grid_matrix(self) -> np.ndarray:
        """3x3 affine: continuous pixel (u, v) -> grid metres (for composing pixel affines)."""
        r = self.resolution
        return np.array([[r, 0.0, 0.5 * r], [0.0, -r, (self.height - 0.5) * r], [0.0, 0.0, 1.0]])

    @staticmethod
    def centred(resolution: float, half: int) -> 'GridFrame':
        """A (2 half + 1)^2 grid whose centre cell's centre is the world origin (a scan's
        local map, laser at the centre)."""
        corner = -(half + 0.5) * resolution
        return GridFrame(resolution, 2 * half + 1, 2 * half + 1, Rigid2D(corner, corner, 0.0))
