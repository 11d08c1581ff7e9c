"""Local map from one scan (thesis §3.1) and its preprocessing (§2.3).

The local map is an image at the global map's resolution with the laser at its centre
and side 2 x range_max. Obstacles are 255 on 0 — the inverse of the thesis's black-on-
white drawings, which is the polarity matchTemplate and feature detectors want against
the map's wall image (`OccupancyMap.surface_image()`). Hence the thesis's *opening* of the black-on-white image
(which grows black points and joins a wall's dotted returns into a line, its fig. 2.5)
is here a morphological *closing* of the obstacle pixels: the same operation, named here
for what it does (`closing_kernel`; the ROS parameter and the CLI flag keep the thesis's
name, `opening_kernel`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .grid_frame import GridFrame
from .scan import ScanPoints
from .transform import Rigid2D


@dataclass
class LocalGrid:
    image: np.ndarray        # uint8 (h, w), 255 = obstacle
    resolution: float
    laser_px: tuple          # continuous pixel (u, v) of the laser origin
    crop_offset: tuple = (0, 0)   # (x0, y0) columns / rows removed on the left / top

    @property
    def height(self) -> int:
        return self.image.shape[0]

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def frame(self) -> GridFrame:
        """The image's own grid frame (origin at its lower-left corner)."""
        return GridFrame(self.resolution, self.width, self.height)

    def grid_T_laser(self) -> Rigid2D:
        """The laser's pose in this image's grid frame; its x axis points along +u."""
        return self.frame.pixel_pose_to_world(*self.laser_px, 0.0)


def rasterize(points: ScanPoints, resolution: float, laser_yaw: float = 0.0, max_range: float = math.inf) -> LocalGrid:
    """Draw the scan's points (rotated by `laser_yaw`) into a (2R/res + 1)^2 image with the
    laser at the centre pixel; R: the farthest point's range, at most `max_range` (farther
    points are left out: a scan's range_max may be huge, and nothing beyond the map's
    extent can match it)."""
    farthest = float(np.hypot(points.points[:, 0], points.points[:, 1]).max(initial=0.0))
    half = int(np.ceil(min(farthest, max_range) / resolution)) + 1
    frame = GridFrame.centred(resolution, half)
    cells = frame.cell_of(Rigid2D(0.0, 0.0, laser_yaw).apply(points.points))
    keep = frame.contains(cells)
    image = np.zeros((frame.height, frame.width), dtype=np.uint8)
    image[cells[keep, 1], cells[keep, 0]] = 255
    return LocalGrid(image, resolution, (float(half), float(half)))


def crop_to_obstacles(grid: LocalGrid, margin: int = 0) -> LocalGrid:
    """Crop to the bounding box of the obstacle pixels (plus `margin`), remembering the
    offsets so a match in the crop still gives the laser pose."""
    ys, xs = np.nonzero(grid.image)
    if len(xs) == 0:
        return grid
    x0 = max(int(xs.min()) - margin, 0)
    y0 = max(int(ys.min()) - margin, 0)
    x1 = min(int(xs.max()) + margin + 1, grid.width)
    y1 = min(int(ys.max()) + margin + 1, grid.height)
    u, v = grid.laser_px
    return LocalGrid(grid.image[y0:y1, x0:x1].copy(), grid.resolution, (u - x0, v - y0),
                     (grid.crop_offset[0] + x0, grid.crop_offset[1] + y0))


def close_obstacles(grid: LocalGrid, kernel: int) -> LocalGrid:
    """A morphological closing of the obstacle pixels (the thesis's opening of obstacles drawn
    black on white) with a kernel x kernel square; 0 or 1 leaves the grid unchanged. Too
    large a kernel joins nearby corners (thesis fig. 2.6)."""
    if kernel <= 1:
        return grid
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (kernel, kernel))
    return LocalGrid(cv2.morphologyEx(grid.image, cv2.MORPH_CLOSE, k), grid.resolution,
                     grid.laser_px, grid.crop_offset)


def build_local_grid(points: ScanPoints, resolution: float, closing_kernel: int,
                     laser_yaw: float = 0.0, max_range: float = math.inf) -> LocalGrid:
    """Scan points -> rasterized, cropped, morphologically closed local map (points up to max_range)."""
    return close_obstacles(crop_to_obstacles(rasterize(points, resolution, laser_yaw, max_range)), closing_kernel)


def soften(image: np.ndarray) -> np.ndarray:
    """A one-cell Gaussian blur, applied alike to the map image and a local map: one-pixel
    lines a sub-cell apart (rasterization, rotation) then still overlap, and feature
    detectors see gradients instead of dots."""
    return cv2.GaussianBlur(image, (5, 5), 1.0)
