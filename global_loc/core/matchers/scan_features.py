"""`features`: keypoints and descriptors chosen for laser data, matched against views of the
map as the laser would see them (ours; the thesis's image features, features.py, find
almost nothing on a scan's local map: docs/decisions/0021).

Built once per map (`ViewFeatures`): viewpoints on free space every `view_spacing_m` (at
least `clearance_m` from obstacles, at most `max_views`: sparser on a large map), from each a
360 deg view ray-cast to `view_range_m`, and the view's points described as a scan's are
(point_features.py: corner, line-end and blob keypoints on the metric point set, oriented
to their neighbours, shape-context descriptors), at their place in the map. The same corner
seen from neighbouring viewpoints gives near-identical descriptors: of those closer than
`same_descriptor` at one place and heading only the first is kept.

A scan: its keypoints described; each descriptor's nearest map descriptors by FLANN (k-d
trees), the first `places` distinct places among them kept as correspondences; rigid poses
from them by one-sample RANSAC (point_features.pose_votes); the best `poses` refined on the
map's distance field (Gauss-Newton on the scan's points, a few steps) and ranked by how
well the map explains the scan there. A fast proposer: the Localizer checks its hypotheses
on the map (verify.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..pixel_kernels import first_hits
from ..transform import Rigid2D
from .base import Candidate, Match, Matcher
from .features import FLANN_INDEX_KDTREE
from .point_features import DIMENSIONS, PointFeatureOptions, point_features, pose_votes

VIEW_CHUNK = 128              # views ray-cast at a time (their hits: 128 x rays x 8 bytes)
# The kept descriptors' share of the memory budget (matchers/__init__.py: BUILD_BYTES_PER_CELL): FLANN
# merges them into a copy of its own while ours exist, so twice this is the peak's share; a map whose
# views see more distinct features keeps an even share of them
DESCRIPTOR_BYTES_PER_CELL = 56
FEATURE_BYTES = 4 * DIMENSIONS + 3 * 8     # a descriptor (float32), its place and orientation
DEDUPLICATE_ROWS = 256


@dataclass(frozen=True)
class ScanFeatureOptions:
    """The precomputation's and the search's settings (docs/decisions/0021 has the figures)."""
    points: PointFeatureOptions = field(default_factory=PointFeatureOptions)
    view_spacing_m: float = 0.5
    clearance_m: float = 0.3
    max_views: int = 3000
    view_range_m: float = 20.0
    view_rays: int = 1440
    same_descriptor: float = 0.15   # L2 between square-rooted shares (0..sqrt 2)
    neighbours: int = 48            # FLANN neighbours asked per scan descriptor
    places: int = 12                # distinct map places kept of them
    same_place_m: float = 0.3
    poses: int = 16                 # poses refined and ranked
    refine_steps: int = 8
    refine_reach_m: float = 0.5     # points farther from a wall are left out of a step
    fit_sigma_cells: float = 2.0


def viewpoints(occupancy_map, o: ScanFeatureOptions) -> np.ndarray:
    """(n, 2) pixel positions of the views: free cells on a grid, clear of obstacles."""
    res = occupancy_map.resolution
    clear = cv2.distanceTransform(occupancy_map.free.astype(np.uint8), cv2.DIST_L2, 3) * res >= o.clearance_m
    step = max(1, int(round(o.view_spacing_m / res)))
    while True:
        vs, us = np.nonzero(clear[::step, ::step])
        if len(us) <= o.max_views:
            return np.stack([us * step, vs * step], axis=1)
        step = int(math.ceil(step * math.sqrt(len(us) / o.max_views)))


def first_of_each(xy: np.ndarray, theta: np.ndarray, descriptors: np.ndarray, o: ScanFeatureOptions) -> np.ndarray:
    """Which map features to keep: of those at one place (same_place_m) and heading (30 deg)
    whose descriptors lie within same_descriptor of an earlier one, the first."""
    cell = np.floor(xy / o.same_place_m).astype(np.int64)
    turn = np.floor((theta % (2 * math.pi)) / math.radians(30)).astype(np.int64)
    key = (cell[:, 0] - cell[:, 0].min()) * 1_000_003 * 12 + (cell[:, 1] - cell[:, 1].min()) * 12 + turn
    order = np.argsort(key, kind='stable')
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    keep = np.ones(len(xy), bool)
    for group in np.split(order, bounds):
        if len(group) < 2:
            continue
        d = descriptors[group].astype(np.float32)
        square = (d * d).sum(axis=1)
        # a busy place (a post seen from a hundred views) has thousands: its distances a block of rows at a time
        for start in range(0, len(group), DEDUPLICATE_ROWS):
            near = square[start:start + DEDUPLICATE_ROWS, None] + square[None] - \
                2 * d[start:start + DEDUPLICATE_ROWS] @ d.T < o.same_descriptor ** 2
            for k, i in enumerate(range(start, min(start + DEDUPLICATE_ROWS, len(group)))):
                if keep[group[i]]:
                    keep[group[i + 1:][near[k, i + 1:]]] = False
    return keep


def view_features(occupancy_map, views: np.ndarray, o: ScanFeatureOptions):
    """The features of each view from the pixels `views`: 360 deg ray-cast, as a scan (in grid metres)."""
    angles = np.linspace(-math.pi, math.pi, o.view_rays, endpoint=False)
    poses = np.column_stack([views, np.zeros(len(views))]).astype(float)
    hits = first_hits(occupancy_map.occupied.view(np.uint8), poses, angles,
                      np.full(o.view_rays, o.view_range_m / occupancy_map.resolution), 0.5)
    for (u, v), view_hits in zip(views, hits, strict=True):
        ok = np.isfinite(view_hits)
        if ok.sum() >= 3:
            # rows grow downwards (pixel_kernels.image_point)
            at = np.stack([u + view_hits[ok] * np.cos(angles[ok]), v - view_hits[ok] * np.sin(angles[ok])], axis=1)
            yield point_features(occupancy_map.frame.pixel_to_grid(at), True, o.points)


class ViewFeatures:
    """The map's keypoints (grid-frame metres), orientations and descriptors, seen from its views."""

    def __init__(self, occupancy_map, o: ScanFeatureOptions):
        views = viewpoints(occupancy_map, o)
        xy, theta, descriptors = [np.zeros((0, 2))], [np.zeros(0)], [np.zeros((0, DIMENSIONS), np.float16)]
        self.seen = 0
        for start in range(0, len(views), VIEW_CHUNK):
            seen = list(view_features(occupancy_map, views[start:start + VIEW_CHUNK], o))
            if not seen:
                continue
            # duplicates within a chunk (neighbouring views along its rows) go at once, the rest at the end
            chunk = (np.vstack([f.xy for f in seen]), np.concatenate([f.theta for f in seen]),
                     np.vstack([f.descriptors for f in seen]).astype(np.float16))    # half, until the end
            self.seen += len(chunk[0])
            first = first_of_each(*chunk, o)
            for part, kept in zip((xy, theta, descriptors), chunk, strict=True):
                part.append(kept[first])
        self.views = len(views)
        xy, theta, descriptors = np.vstack(xy), np.concatenate(theta), np.vstack(descriptors)
        keep = np.flatnonzero(first_of_each(xy, theta, descriptors, o)) if len(xy) else []
        cap = int(DESCRIPTOR_BYTES_PER_CELL * occupancy_map.width * occupancy_map.height / FEATURE_BYTES)
        if len(keep) > cap:       # within the memory budget: an even, seeded share of the places
            keep = np.sort(np.random.default_rng(0).choice(keep, cap, replace=False))
        self.xy, self.theta = xy[keep], theta[keep]
        self.descriptors = np.ascontiguousarray(descriptors[keep], dtype=np.float32)

    @property
    def nbytes(self) -> int:
        return self.xy.nbytes + self.theta.nbytes + self.descriptors.nbytes


class ScanFeatureMatcher(Matcher):
    """Laser keypoints of the scan matched to those of the map's views; see the module docstring."""
    name = 'features'
    min_score = 0.3      # the map explains about a third of the scan at the best pose

    def __init__(self, occupancy_map, options: ScanFeatureOptions | None = None):
        super().__init__(occupancy_map)
        self.options = options or ScanFeatureOptions()
        self.features = ViewFeatures(occupancy_map, self.options)
        self.field = occupancy_map.distance_to_occupied()       # cells, float32
        self.flann = cv2.FlannBasedMatcher(dict(algorithm=FLANN_INDEX_KDTREE, trees=4), dict(checks=64))
        if len(self.features.xy) >= self.options.neighbours:
            # the k-d trees' splits are drawn from OpenCV's per-thread RNG: seeded, one map one index
            cv2.setRNGSeed(0)
            self.flann.add([self.features.descriptors])
            self.flann.train()
        # FLANN keeps its own merged copy for the search: ours would only double it
        self.features.descriptors = np.zeros((0, DIMENSIONS), np.float32)

    @property
    def nbytes(self) -> int:
        """The views' features (their descriptors in FLANN's copy) and the distance field, as kept for the search."""
        return self.features.nbytes + len(self.features.xy) * 4 * DIMENSIONS + self.field.nbytes

    def correspondences(self, scan) -> tuple | None:
        """(scan keypoint index, map xy, map orientation) arrays: each scan descriptor's
        nearest map descriptors, the first `places` distinct places among them."""
        o, mapped = self.options, self.features
        if len(scan.xy) == 0 or len(mapped.xy) < o.neighbours:
            return None
        found = self.flann.knnMatch(scan.descriptors, k=o.neighbours)
        train = np.array([[n.trainIdx for n in row] + [-1] * (o.neighbours - len(row)) for row in found])
        at = mapped.xy[np.maximum(train, 0)]                          # (scan keypoints, neighbours, 2)
        gap = np.linalg.norm(at[:, :, None] - at[:, None, :], axis=3)
        # a neighbour at the place of a nearer one is that place again (the same corner from another view)
        again = np.tril(gap < o.same_place_m, k=-1).any(axis=2) | (train < 0)
        first = ~again & (np.cumsum(~again, axis=1) <= o.places)
        query, column = np.nonzero(first)
        picked = train[query, column]
        return query, mapped.xy[picked], mapped.theta[picked]

    def match(self, points, options, progress=None):
        scan = point_features(points.points, points.beams, self.options.points)
        ends = self.correspondences(scan)
        if progress:
            progress(0.5, 0.0)
        if ends is None or len(ends[0]) == 0:
            return Match([])
        sample = points.points[::max(1, len(points.points) // 300)]
        votes = pose_votes(scan, ends, self.options.points, self.options.poses)
        poses = self.refined(np.array([self.pixel_pose(pose) for pose, _ in votes]), sample)
        candidates = [Candidate(self.map.frame.pixel_pose_to_world(*pose), float(fit))
                      for pose, fit in zip(poses, self.fit(poses, sample), strict=True)]
        if progress:
            progress(1.0, max((c.score for c in candidates), default=0.0))
        return Match(self.distinct(candidates))

    def pixel_pose(self, grid_pose: Rigid2D) -> tuple[float, float, float]:
        u, v = self.map.frame.grid_to_pixel([[grid_pose.x, grid_pose.y]])[0]
        return float(u), float(v), grid_pose.yaw

    def field_at(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The distance field (cells) at continuous pixels, bilinear, and its slopes along u and v."""
        height, width = self.field.shape
        u, v = np.clip(u, 0, width - 1.001), np.clip(v, 0, height - 1.001)
        u0, v0 = u.astype(int), v.astype(int)
        fu, fv = u - u0, v - v0
        f = self.field
        a, b, c, d = f[v0, u0], f[v0, u0 + 1], f[v0 + 1, u0], f[v0 + 1, u0 + 1]
        value = a * (1 - fu) * (1 - fv) + b * fu * (1 - fv) + c * (1 - fu) * fv + d * fu * fv
        return value, (b - a) * (1 - fv) + (d - c) * fv, (c - a) * (1 - fu) + (d - b) * fu

    def projected(self, poses: np.ndarray, pts: np.ndarray) -> tuple:
        """Laser-frame points at each laser pose (u, v, yaw) in pixels: (poses, points) arrays
        of their pixels and their offsets from the laser (rows grow downwards)."""
        c, s, res = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3]), self.map.resolution
        du, dv = (c * pts[:, 0] - s * pts[:, 1]) / res, -(s * pts[:, 0] + c * pts[:, 1]) / res
        return poses[:, 0:1] + du, poses[:, 1:2] + dv, du, dv

    def refined(self, poses: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """The pixel poses (u, v, yaw) moved by Gauss-Newton steps toward the walls nearest
        the scan's points (those within refine_reach_m, half of it after three steps)."""
        o = self.options
        poses = poses.copy()
        reach = o.refine_reach_m / self.map.resolution
        for step in range(o.refine_steps):
            pu, pv, du, dv = self.projected(poses, pts)
            d, gu, gv = self.field_at(pu, pv)
            near = (d < (reach if step < 3 else reach / 2)).astype(float)
            # d(pu)/d(yaw) = dv, d(pv)/d(yaw) = -du (a turn of the offsets, rows down)
            jac = np.stack([gu, gv, gu * dv - gv * du], axis=2) * near[..., None]
            normal = np.einsum('hpi,hpj->hij', jac, jac) + 1e-6 * np.eye(3)
            delta = -np.linalg.solve(normal, np.einsum('hpi,hp->hi', jac, d)[..., None])[..., 0]
            delta[near.sum(axis=1) < 5] = 0.0       # too few points near a wall: left where it is
            poses += np.clip(delta, [-4, -4, -0.1], [4, 4, 0.1])
        return poses

    def fit(self, poses: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """How well the map explains the points at each pose: mean exp(-d^2 / 2 sigma^2), d in cells."""
        pu, pv, _, _ = self.projected(poses, pts)
        d = self.field_at(pu, pv)[0]
        return np.exp(-0.5 * (d / self.options.fit_sigma_cells) ** 2).mean(axis=1)
