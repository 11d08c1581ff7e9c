"""Pose from a match (thesis §2.5, eq. 2.18), as composed 2-D transforms.

A matcher finds a pixel affine `A` (3x3, pixel -> pixel, rotation + translation in
image coordinates, y down) taking the local map's pixels onto the global map's pixels.
The laser pose in the map frame is then

    map_T_laser = map.origin * G_map * A * G_local^-1 * local.grid_T_laser()

where G_* converts an image's pixels to its grid frame (GridFrame.pixel_to_grid_matrix).
A rotation by +a in pixel coordinates (y down) is a rotation by -a in the grid frame;
composing the matrices takes care of that and of crops, canvas growth and map-origin yaw
at once.
"""
from __future__ import annotations

import math

import numpy as np

from .local_grid import LocalGrid
from .map_io import OccupancyMap
from .transform import Rigid2D


def translation_px(du: float, dv: float) -> np.ndarray:
    return np.array([[1.0, 0.0, du], [0.0, 1.0, dv], [0.0, 0.0, 1.0]])


def rotation_px(angle_deg: float, center) -> np.ndarray:
    """3x3 form of cv2.getRotationMatrix2D(center, angle_deg, 1): turns the image
    counter-clockwise on screen (= +angle in the y-up grid frame) about `center`."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    cx, cy = center
    return np.array([[c, s, (1 - c) * cx - s * cy],
                     [-s, c, s * cx + (1 - c) * cy],
                     [0.0, 0.0, 1.0]])


def pose_from_match(occupancy_map: OccupancyMap, local: LocalGrid, local_to_map_px) -> Rigid2D:
    """Laser pose in the map frame, given the pixel affine from `local`'s image to the
    map image. A uniform scale in the affine (feature matching) is divided out about the
    laser pixel: the laser lands where the affine puts it, heading from its rotation."""
    a = np.asarray(local_to_map_px, dtype=float)
    if a.shape == (2, 3):
        a = np.vstack([a, [0.0, 0.0, 1.0]])
    scale = math.sqrt(abs(np.linalg.det(a[:2, :2])))
    if scale <= 0:
        raise ValueError('degenerate pixel affine')
    laser = np.array([local.laser_px[0], local.laser_px[1], 1.0])
    target = a @ laser
    a = a.copy()
    a[:2, :2] /= scale
    a[:2, 2] = target[:2] - a[:2, :2] @ laser[:2]
    g_map = occupancy_map.frame.pixel_to_grid_matrix()
    g_local = local.frame.pixel_to_grid_matrix()
    grid_T_localgrid = Rigid2D.from_matrix(g_map @ a @ np.linalg.inv(g_local))
    return occupancy_map.origin * grid_T_localgrid * local.grid_T_laser()
