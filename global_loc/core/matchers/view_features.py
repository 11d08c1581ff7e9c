"""Features matched against views of the map as the laser would see them (ours; the
thesis's feature path, features.py, describes the map image itself and finds almost
nothing: a scan shows the surfaces visible from one place, the map image every wall, so
few descriptors agree).

Built once per map: viewpoints on free space every VIEW_SPACING_M (at least CLEARANCE_M
from obstacles, at most MAX_VIEWS of them: sparser on a large map), from each a 360° view
ray-cast to VIEW_RANGE_M, drawn, closed and turned into a wall field (local_grid.wall_field),
and its SIFT keypoints kept at their map pixels. A scan's local map is described the same
way; each of its descriptors is matched to the nearest map descriptor that stands clear of
the next one *from another place* (Lowe's ratio test, among places: the same corner seen
from two viewpoints is one place, not an ambiguity), and sequential RANSAC fits rigid
poses (features.LocalFeatureMatcher, as the thesis's path). A fast proposer: the
Localizer checks its hypotheses on the map.
Measured on 20 simulated 270°/20 m scans: the best fit right (< 0.5 m) on 6-8 of 20 at the
office, 13 of 20 at building_31; 7-17 ms a scan; built in 2 s (office) and 18 s (building_31).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..local_grid import wall_field
from ..pixel_kernels import first_hits
from .features import LocalFeatureMatcher

VIEW_SPACING_M = 1.0
CLEARANCE_M = 0.3
MAX_VIEWS = 3000
VIEW_RANGE_M = 20.0
VIEW_RAYS = 1440
FIELD_REACH_PX = 8.0
SAME_PLACE_PX = 10.0        # two map keypoints closer than this are one place (ratio test)
NEIGHBOURS = 8


def viewpoints(occupancy_map) -> np.ndarray:
    """(n, 2) pixel positions of the views: free cells on a grid, clear of obstacles."""
    res = occupancy_map.resolution
    clear = cv2.distanceTransform(occupancy_map.free.astype(np.uint8), cv2.DIST_L2, 3) * res >= CLEARANCE_M
    step = max(1, int(round(VIEW_SPACING_M / res)))
    while True:
        vs, us = np.nonzero(clear[::step, ::step])
        if len(us) <= MAX_VIEWS:
            return np.stack([us * step, vs * step], axis=1)
        step = int(math.ceil(step * math.sqrt(len(us) / MAX_VIEWS)))


def view_image(hits_px: np.ndarray, u: int, v: int, angles: np.ndarray, pad: int = 20):
    """The view's returns drawn, cropped to them (+ pad): (image, its top-left map pixel)."""
    ok = np.isfinite(hits_px)
    x = u + hits_px[ok] * np.cos(angles[ok])
    y = v - hits_px[ok] * np.sin(angles[ok])      # image rows grow downwards (pixel_kernels.image_point)
    x0, y0 = int(np.floor(x.min())) - pad, int(np.floor(y.min())) - pad
    image = np.zeros((int(np.ceil(y.max())) + pad - y0 + 1, int(np.ceil(x.max())) + pad - x0 + 1), np.uint8)
    image[np.round(y - y0).astype(int), np.round(x - x0).astype(int)] = 255
    return cv2.morphologyEx(image, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)), (x0, y0)


class ViewFeatureMatcher(LocalFeatureMatcher):
    """Descriptors of the map's views; Lowe's ratio test among places."""
    name = 'features_views'

    def __init__(self, occupancy_map):
        super().__init__(occupancy_map)
        self.detector = cv2.SIFT_create(nfeatures=1000)
        views = viewpoints(occupancy_map)
        angles = np.linspace(-math.pi, math.pi, VIEW_RAYS, endpoint=False)
        poses = np.column_stack([views, np.zeros(len(views))]).astype(float)
        hits = first_hits(occupancy_map.occupied.astype(np.uint8), poses, angles,
                          np.full(VIEW_RAYS, VIEW_RANGE_M / occupancy_map.resolution), 0.5)
        points, descriptors = [], []
        for (u, v), view_hits in zip(views, hits, strict=True):
            if not np.isfinite(view_hits).any():
                continue
            image, (x0, y0) = view_image(view_hits, int(u), int(v), angles)
            kps, desc = self.detector.detectAndCompute(self.prepared(image), None)
            if desc is not None:
                points += [(kp.pt[0] + x0, kp.pt[1] + y0) for kp in kps]
                descriptors.append(desc)
        self.views = len(views)
        self.map_points = np.float32(points).reshape(-1, 2)
        self.flann = cv2.FlannBasedMatcher(dict(algorithm=1, trees=5), dict(checks=64))
        if descriptors:
            self.flann.add([np.vstack(descriptors)])
            self.flann.train()

    def prepared(self, image):
        return wall_field(image, FIELD_REACH_PX)

    def pairs(self, keypoints, descriptors):
        if len(self.map_points) < NEIGHBOURS:
            return None
        src, dst = [], []
        for neighbours in self.flann.knnMatch(descriptors, k=NEIGHBOURS):
            if not neighbours:
                continue
            best = neighbours[0]
            at = self.map_points[best.trainIdx]
            other = next((n for n in neighbours[1:]
                          if np.hypot(*(self.map_points[n.trainIdx] - at)) > SAME_PLACE_PX), None)
            if other is None or best.distance < self.ratio * other.distance:
                src.append(keypoints[best.queryIdx].pt)
                dst.append(at)
        return np.float32(src).reshape(-1, 2), np.float32(dst).reshape(-1, 2)
