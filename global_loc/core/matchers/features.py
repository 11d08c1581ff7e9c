"""Feature matching (thesis §2.2): keypoints and descriptors in the local map and the
map image, FLANN nearest neighbours with Lowe's ratio test, and a RANSAC rigid fit
(cv2.estimateAffinePartial2D). SURF where this OpenCV build has it (opencv-contrib
with nonfree), else ORB, SIFT or AKAZE.

Sequential RANSAC gives more than one hypothesis: after a fit, its inliers are removed
and the rest fitted again. The score is the inlier count.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..local_grid import build_local_grid, soften
from ..pose import pose_from_match
from .base import Candidate, Match, Matcher, MethodError

FLANN_INDEX_KDTREE = 1
FLANN_INDEX_LSH = 6


def surf_available() -> bool:
    try:
        cv2.xfeatures2d.SURF_create()
        return True
    except (AttributeError, cv2.error):
        return False


def make_detector(name: str):
    """(detector, is_binary) for 'surf', 'orb', 'sift' or 'akaze'."""
    if name == 'surf':
        if not surf_available():
            raise MethodError('SURF is not in this OpenCV build (it needs opencv-contrib built with '
                              'OPENCV_ENABLE_NONFREE); use features_orb, features_sift or features_akaze')
        return cv2.xfeatures2d.SURF_create(hessianThreshold=300), False
    if name == 'orb':
        return cv2.ORB_create(nfeatures=20000, scaleFactor=1.2, nlevels=4, edgeThreshold=15, patchSize=15,
                              fastThreshold=10), True
    if name == 'sift':
        return cv2.SIFT_create(), False
    if name == 'akaze':
        if not hasattr(cv2, 'AKAZE_create'):   # OpenCV 5 moved AKAZE out of the main modules
            raise MethodError(f'AKAZE is not in this OpenCV build ({cv2.__version__}); '
                              'use features_orb or features_sift')
        return cv2.AKAZE_create(threshold=0.0005), True
    raise MethodError(f'unknown feature detector {name!r}; known: surf, orb, sift, akaze')


def rigid_fits(src: np.ndarray, dst: np.ndarray, pose_of, min_inliers: int, max_fits: int,
               max_scale_error: float) -> list[Candidate]:
    """Sequential RANSAC (cv2.estimateAffinePartial2D) of matched pixel pairs src -> dst:
    after a fit its inliers are removed and the rest fitted again, up to max_fits fits of
    at least min_inliers inliers; a fit whose scale is off 1 by more than max_scale_error
    (both images share the resolution) is no pose. Candidates `pose_of(affine)` scored by
    their inlier count, best first."""
    candidates = []
    # RANSAC draws from OpenCV's per-thread RNG: seeded, the same scan gets the same
    # answer whatever ran in this thread before (it did not: a test passed alone and
    # failed after others)
    cv2.setRNGSeed(0)
    while len(src) >= min_inliers and len(candidates) < max_fits:
        affine, inliers = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=3.0,
                                                      maxIters=5000, confidence=0.995)
        if affine is None:
            break
        inliers = inliers.ravel().astype(bool)
        if inliers.sum() < min_inliers:
            break
        if abs(math.hypot(affine[0, 0], affine[1, 0]) - 1.0) <= max_scale_error:
            candidates.append(Candidate(pose_of(affine), float(inliers.sum())))
        src, dst = src[~inliers], dst[~inliers]
    return sorted(candidates, key=lambda c: -c.score)


class LocalFeatureMatcher(Matcher):
    """A scan's local map described by a detector and its descriptors paired with the map's,
    the pairs fitted by sequential RANSAC (rigid_fits). A subclass says how an image is
    prepared for the detector (`prepared`) and how descriptors are paired (`pairs`)."""
    min_score = 8           # inliers
    ratio = 0.8             # Lowe's ratio test
    max_scale_error = 0.15  # both images share the resolution: scale must be ~1
    max_hypotheses = 3
    detector = None

    def prepared(self, image: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def pairs(self, keypoints, descriptors):
        """(src, dst): the scan's keypoints and the map pixels they are paired with; None
        when the map has too few descriptors to pair with."""
        raise NotImplementedError

    def match(self, points, options, progress=None):
        self.check_local_map_budget(points)
        local = build_local_grid(points, self.map.resolution, options.closing_kernel,
                                 max_range=self.map.diagonal_m)
        kps, desc = self.detector.detectAndCompute(self.prepared(local.image), None)
        if progress:
            progress(0.3, 0.0)
        paired = None if desc is None or len(kps) < 3 else self.pairs(kps, desc)
        if paired is None:
            return Match([])
        candidates = rigid_fits(*paired, lambda affine: pose_from_match(self.map, local, affine), self.min_score,
                                self.max_hypotheses, self.max_scale_error)
        if progress:
            progress(1.0, candidates[0].score if candidates else 0.0)
        return Match(self.distinct(candidates))


class FeatureMatcher(LocalFeatureMatcher):
    """The thesis's path: the map image itself described, Lowe's ratio test."""

    def __init__(self, occupancy_map, detector_name: str):
        super().__init__(occupancy_map)
        self.name = f'features_{detector_name}'
        self.detector, binary = make_detector(detector_name)
        self.keypoints, self.descriptors = self.detector.detectAndCompute(
            soften(occupancy_map.surface_image()), None)
        if binary:
            # 12 hash tables: with 6, a place the matcher knows was missed on 1 index in 10
            index = dict(algorithm=FLANN_INDEX_LSH, table_number=12, key_size=12, multi_probe_level=1)
        else:
            index = dict(algorithm=FLANN_INDEX_KDTREE, trees=5)
        self.flann = cv2.FlannBasedMatcher(index, dict(checks=64))
        if self.descriptors is not None and len(self.keypoints) >= 2:
            self.flann.add([self.descriptors])
            # LSH's hash bits and the k-d trees' splits are drawn from OpenCV's per-thread
            # RNG: seeded, the same map gets the same index whatever ran before it
            cv2.setRNGSeed(0)
            self.flann.train()
        self.map_points = np.float32([kp.pt for kp in self.keypoints]).reshape(-1, 2)

    def prepared(self, image):
        return soften(image)

    @property
    def nbytes(self) -> int:
        """The map's descriptors and keypoint pixels, as kept for the search."""
        return (0 if self.descriptors is None else self.descriptors.nbytes) + self.map_points.nbytes

    def pairs(self, keypoints, descriptors):
        if len(self.keypoints) < 3:
            return None
        pairs = self.flann.knnMatch(descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < self.ratio * p[1].distance]
        return (np.float32([keypoints[m.queryIdx].pt for m in good]).reshape(-1, 2),
                self.map_points[[m.trainIdx for m in good]].reshape(-1, 2))
