"""Compiled (numba) loops over a grid's cells that more than one part of the package
needs: where a laser-frame point lands in the image (`image_point`, the kernels' copy of
GridFrame's "rows grow downwards"), and marching rays to their first occupied cell
(`first_hits`: the simulator's ray caster and bnb's free-space check).

Poses here are (u, v, yaw): the laser at continuous pixel (u, v) with grid-frame heading
yaw (GridFrame.world_pose_to_pixel); lengths and steps are in cells.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline='always')
def image_point(u, v, c, s, px, py):
    """The pixel position of laser-frame point (px, py) for a laser at pixel (u, v) with
    grid-frame heading (cos, sin) = (c, s): x turns with the heading, rows grow downwards."""
    return u + c * px - s * py, v - (s * px + c * py)


@njit(cache=True, nogil=True)
def first_hits(occupied, poses, angles, lengths, step):
    """(poses, rays): how far (cells) each ray, at laser-frame angle angles[i] from each
    pose, runs before the first occupied cell it steps on, walking in `step`-cell steps
    from `step` while shorter than lengths[i]; inf where it meets none."""
    height, width = occupied.shape
    out = np.full((poses.shape[0], len(angles)), np.inf)
    for k in range(poses.shape[0]):
        for i in range(len(angles)):
            c = math.cos(poses[k, 2] + angles[i])
            s = math.sin(poses[k, 2] + angles[i])
            t = step
            while t < lengths[i]:
                fx, fy = image_point(poses[k, 0], poses[k, 1], c, s, t, 0.0)
                x, y = int(round(fx)), int(round(fy))
                if 0 <= x < width and 0 <= y < height and occupied[y, x]:
                    out[k, i] = t
                    break
                t += step
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels here."""
    first_hits(np.zeros((2, 2), np.uint8), np.zeros((1, 3)), np.zeros(1), np.ones(1), 0.5)
