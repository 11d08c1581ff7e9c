"""Keypoints and descriptors of a laser's points, in metres (after FLIRT, Tipaldi and Arras
2010): what `features` (scan_features.py) describes on a scan and on views of the map.

A point set - a scan's returns in beam order, a view's ray hits, or unordered wall cells - is
first made a contour of even density: consecutive points closer than GAP_M are joined and
the whole thinned to one point per `resample_m` cell, so that a wall counts by its length,
not by how far from the laser it stood. On that contour:

- keypoints: corners (the smaller eigenvalue of the points within `key_radius_m`, relative to
  their spread), line ends (the neighbours' centroid far off the point) and blobs (a point
  with few neighbours: a leg, a post, a sparse map's lone wall cells), one per
  `suppress_m`, the `max_keypoints` strongest;
- orientation: the direction from the keypoint to the centroid of the points around it,
  weighted by exp(-r / orient_m): defined at corners, ends and blobs alike, and it turns with
  the scan - the scan's heading is unknown, so the descriptor is read in this frame;
- descriptor: a shape context - the share of the contour's points in each of RINGS x SECTORS
  log-polar bins out to `describe_m`, in the keypoint's frame, square-rooted (Hellinger:
  FLANN's L2 then compares the shares' roots, which weighs a sparse bin fairly).

`pose_votes` turns oriented correspondences into rigid poses: one correspondence and the two
orientations fix a pose (a one-sample RANSAC, every sample tried); its inliers are the
correspondences it carries to within `inlier_m` and `inlier_deg`, and the pose is refitted to
them by least squares. Poses are ranked by how many scan keypoints they explain.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from ..scan import voxel_filter
from ..transform import Rigid2D

RINGS = 5
SECTORS = 12
DIMENSIONS = RINGS * SECTORS
GAP_M = 0.3            # consecutive points closer than this lie on one surface (joined)
INNER_RING_M = 0.15    # the innermost ring's outer radius


@dataclass(frozen=True)
class PointFeatureOptions:
    """How a point set is described (each field documented in the module docstring)."""
    resample_m: float = 0.1
    key_radius_m: float = 0.5
    key_neighbours: int = 16
    min_neighbours: int = 5        # fewer within key_radius_m: a blob
    corner_min: float = 0.03       # smaller / total eigenvalue
    end_min: float = 0.3           # centroid offset / key_radius_m
    suppress_m: float = 0.35
    max_keypoints: int = 40        # the strongest; the pose votes cost grows with their square
    orient_m: float = 1.0
    describe_m: float = 3.0
    inlier_m: float = 0.4
    inlier_deg: float = 25.0


class PointFeatures(NamedTuple):
    xy: np.ndarray          # (n, 2) keypoints, metres
    theta: np.ndarray       # (n,) orientations, radians
    descriptors: np.ndarray  # (n, DIMENSIONS) float32


def no_features() -> PointFeatures:
    return PointFeatures(np.zeros((0, 2)), np.zeros(0), np.zeros((0, DIMENSIONS), np.float32))


def contour(points: np.ndarray, ordered: bool, resample_m: float) -> np.ndarray:
    """The points as a contour of even density (see the module docstring)."""
    if ordered and len(points) > 1:
        step = np.diff(points, axis=0)
        length = np.hypot(step[:, 0], step[:, 1])
        parts = np.where((length < GAP_M) & (length > resample_m / 2),
                         np.ceil(2 * length / resample_m).astype(int), 1)
        joined = np.nonzero(parts > 1)[0]
        if len(joined):
            counts = parts[joined] - 1
            at = np.repeat(joined, counts)
            first = np.repeat(np.cumsum(counts) - counts, counts)
            t = (np.arange(len(at)) - first + 1) / np.repeat(parts[joined], counts)
            points = np.vstack([points, points[at] + t[:, None] * step[at]])
    return voxel_filter(points, resample_m)


def keypoint_scores(pts: np.ndarray, tree: cKDTree, o: PointFeatureOptions) -> tuple[np.ndarray, np.ndarray]:
    """(score, candidate): how corner-, end- or blob-like each point is (>= 1: a keypoint)."""
    d, idx = tree.query(pts, k=min(o.key_neighbours, len(pts)), distance_upper_bound=o.key_radius_m)
    d, idx = d.reshape(len(pts), -1), idx.reshape(len(pts), -1)
    valid = np.isfinite(d)
    w = valid.astype(float)
    count = w.sum(axis=1)
    around = pts[np.where(valid, idx, 0)]
    mean = (around * w[..., None]).sum(axis=1) / count[:, None]
    rel = (around - mean[:, None]) * w[..., None]
    cxx, cyy = (rel[..., 0] ** 2).sum(axis=1) / count, (rel[..., 1] ** 2).sum(axis=1) / count
    cxy = (rel[..., 0] * rel[..., 1]).sum(axis=1) / count
    trace = cxx + cyy
    smaller = trace / 2 - np.sqrt(np.maximum(trace ** 2 / 4 - (cxx * cyy - cxy ** 2), 0.0))
    corner = smaller / np.maximum(trace, 1e-12)
    end = np.hypot(*(mean - pts).T) / o.key_radius_m
    score = np.maximum(corner / o.corner_min, end / o.end_min)
    blob = count < o.min_neighbours
    return np.where(blob, 1.0 + 0.01 * count, score), blob | (score >= 1.0)


def keypoints(pts: np.ndarray, tree: cKDTree, o: PointFeatureOptions) -> np.ndarray:
    """Indices of the keypoints: the strongest candidate within each suppress_m."""
    score, candidate = keypoint_scores(pts, tree, o)
    taken = ~candidate
    keep = []
    for i in np.argsort(-score):
        if not candidate[i] or len(keep) == o.max_keypoints:
            break
        if not taken[i]:
            keep.append(i)
            taken[tree.query_ball_point(pts[i], o.suppress_m)] = True
    return np.array(keep, int)


def describe(pts: np.ndarray, keys: np.ndarray, o: PointFeatureOptions) -> tuple[np.ndarray, np.ndarray]:
    """(orientations, shape-context descriptors) of the keypoints pts[keys]."""
    rel = pts[None, :, :] - pts[keys][:, None, :]           # (keys, points, 2)
    r = np.hypot(rel[..., 0], rel[..., 1])
    inside = r < o.describe_m
    weight = np.exp(-r / o.orient_m) * inside
    theta = np.arctan2((rel[..., 1] * weight).sum(axis=1), (rel[..., 0] * weight).sum(axis=1))
    phi = (np.arctan2(rel[..., 1], rel[..., 0]) - theta[:, None]) % (2 * math.pi)
    ring = np.searchsorted(np.geomspace(INNER_RING_M, o.describe_m, RINGS), r)
    sector = np.minimum((phi * (SECTORS / (2 * math.pi))).astype(int), SECTORS - 1)
    counted = inside & (ring < RINGS)
    flat = (np.arange(len(keys))[:, None] * DIMENSIONS + ring * SECTORS + sector)[counted]
    hist = np.bincount(flat, minlength=len(keys) * DIMENSIONS).reshape(len(keys), DIMENSIONS).astype(np.float32)
    return theta, np.sqrt(hist / np.maximum(hist.sum(axis=1, keepdims=True), 1.0))


def point_features(points: np.ndarray, ordered: bool, o: PointFeatureOptions) -> PointFeatures:
    """Keypoints, orientations and descriptors of a point set (metres; `ordered`: in beam order)."""
    pts = contour(np.asarray(points, float), ordered, o.resample_m)
    if len(pts) < 3:
        return no_features()
    keys = keypoints(pts, cKDTree(pts), o)
    if len(keys) == 0:
        return no_features()
    theta, descriptors = describe(pts, keys, o)
    return PointFeatures(pts[keys], theta, descriptors)


def rigid_fit(a: np.ndarray, b: np.ndarray) -> Rigid2D:
    """The rigid pose carrying points a onto b with the least squared error."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    da, db = a - ca, b - cb
    yaw = math.atan2(float((da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0]).sum()), float((da * db).sum()))
    turned = Rigid2D(0.0, 0.0, yaw).apply(ca[None])[0]
    return Rigid2D(float(cb[0] - turned[0]), float(cb[1] - turned[1]), yaw)


def pose_votes(scan: PointFeatures, ends: tuple, o: PointFeatureOptions, max_poses: int) -> list[tuple[Rigid2D, int]]:
    """Rigid poses (scan frame -> map frame) from correspondences `ends` = (scan keypoint
    index, map xy, map orientation) arrays, with the number of scan keypoints each
    explains, most first; poses within 0.5 m and 20 deg of a better one left out."""
    query, dst, dst_theta = ends
    src = scan.xy[query].astype(np.float32)
    dst = dst.astype(np.float32)
    yaw = (dst_theta - scan.theta[query]).astype(np.float32)
    c, s = np.cos(yaw), np.sin(yaw)
    tx = dst[:, 0] - (c * src[:, 0] - s * src[:, 1])
    ty = dst[:, 1] - (s * src[:, 0] + c * src[:, 1])
    # hypothesis h (a row) carries correspondence j (a column) to within inlier_m
    ex = c[:, None] * src[None, :, 0] - s[:, None] * src[None, :, 1] + (tx[:, None] - dst[None, :, 0])
    ey = s[:, None] * src[None, :, 0] + c[:, None] * src[None, :, 1] + (ty[:, None] - dst[None, :, 1])
    inliers = ex * ex + ey * ey < o.inlier_m ** 2
    inliers &= np.cos(yaw[None, :] - yaw[:, None]) > math.cos(math.radians(o.inlier_deg))
    keys = np.zeros((len(query), int(query.max()) + 1), np.float32)
    keys[np.arange(len(query)), query] = 1.0
    explained = ((inliers.astype(np.float32) @ keys) > 0).sum(axis=1)
    src, dst = src.astype(float), dst.astype(float)
    poses: list[tuple[Rigid2D, int]] = []
    for h in np.argsort(-explained, kind='stable'):
        if len(poses) == max_poses:
            break
        chosen = inliers[h]
        pose = rigid_fit(src[chosen], dst[chosen]) if chosen.sum() >= 2 else \
            Rigid2D(float(tx[h]), float(ty[h]), float(yaw[h]))
        if all(d >= 0.5 or a >= math.radians(20) for d, a in (pose.distance_to(p) for p, _ in poses)):
            poses.append((pose, int(explained[h])))
    return poses
