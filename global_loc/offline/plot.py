"""Pictures of a localization: the map, the scan placed at the estimate, the estimated
(and, when known, true) pose, and the other hypotheses."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core.map_io import OccupancyMap  # noqa: E402
from ..core.transform import Rigid2D  # noqa: E402


@dataclass(frozen=True)
class DrawnPoses:
    """The poses a picture shows, of the robot base in the map frame: the estimate (the scan
    is drawn there; None: no scan), the truth when known, and the hypotheses best first (the
    first is the estimate's; the others are drawn)."""
    estimate: Optional[Rigid2D]
    truth: Optional[Rigid2D] = None
    hypotheses: Sequence = ()


def plot_localization(path: str, occupancy_map: OccupancyMap, points_laser: np.ndarray, poses: DrawnPoses,
                      base_T_laser: Optional[Rigid2D] = None, title: str = '') -> None:
    """`points_laser`: (N, 2) scan points in the laser frame, `base_T_laser` that frame on
    the base (default: the base itself)."""
    estimate, truth, hypotheses = poses.estimate, poses.truth, poses.hypotheses
    occ = occupancy_map.occupancy
    shade = np.where(occ < 0, 0.8, 1.0 - np.clip(occ, 0, 100) / 100.0)
    h, w = occ.shape
    corners = occupancy_map.frame.pixel_to_world(np.array([[-0.5, h - 0.5], [w - 0.5, -0.5]]))
    fig, ax = plt.subplots(figsize=(9, 9 * h / max(w, 1) + 0.8))
    if abs(occupancy_map.origin.yaw) < 1e-9:
        ax.imshow(shade, cmap='gray', vmin=0, vmax=1, origin='upper', interpolation='nearest',
                  extent=(corners[0, 0], corners[1, 0], corners[0, 1], corners[1, 1]))
    else:   # rotated map origin: draw occupied cells as points in the map frame
        rows, cols = np.nonzero(occupancy_map.occupied)
        xy = occupancy_map.frame.pixel_to_world(np.stack([cols, rows], axis=1))
        ax.plot(xy[:, 0], xy[:, 1], 's', color='k', markersize=1)
    arrow = max(0.6, 0.03 * max(w, h) * occupancy_map.resolution)

    def draw_pose(p: Rigid2D, color, label):
        ax.arrow(p.x, p.y, arrow * math.cos(p.yaw), arrow * math.sin(p.yaw), width=arrow * 0.08,
                 color=color, length_includes_head=True, label=label)

    for i, hyp in enumerate(list(hypotheses)[1:]):
        draw_pose(hyp.pose, 'orange', 'other hypotheses' if i == 0 else None)
    if estimate is not None:
        pts = (estimate * (base_T_laser or Rigid2D())).apply(points_laser)
        ax.plot(pts[:, 0], pts[:, 1], '.', color='red', markersize=2, label='scan at estimate')
        draw_pose(estimate, 'red', 'estimate')
    if truth is not None:
        draw_pose(truth, 'limegreen', 'truth')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_aspect('equal')
    ax.legend(loc='upper right', fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
