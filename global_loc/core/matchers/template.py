"""Rotated template matching (thesis §2.4): the local map, rotated in steps of Δα over
360°, slid over the map image with cv2.matchTemplate.

TM_CCOEFF_NORMED scores in [-1, 1], higher better; TM_SQDIFF_NORMED in [0, 1], lower
better, reported here as 1 - value so that every matcher's higher score is better.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from ..local_grid import build_local_grid, soften
from ..pose import pose_from_match, rotation_px, translation_px
from .base import Candidate, Match, Matcher


class RotatedTemplateMatcher(Matcher):
    """`blur`: soften map and template alike. TM_SQDIFF_NORMED needs it: on unblurred
    one-pixel lines nearly every placement saturates at OpenCV's clamp of 1; on the same
    scans TM_CCOEFF_NORMED does better without."""

    def __init__(self, occupancy_map, cv_method: int, name: str, min_score: float, blur: bool):
        super().__init__(occupancy_map)
        self.blur = soften if blur else (lambda image: image)
        self.cv_method = cv_method
        self.name = name
        self.min_score = min_score
        self.map_image = self.blur(occupancy_map.surface_image())
        # Peaks closer than this are one hypothesis (suppressed in the score image).
        self.peak_radius_px = max(1, int(round(0.5 / occupancy_map.resolution)))

    def match(self, points, options, progress=None):
        local = build_local_grid(points, self.map.resolution, options.opening_kernel)
        angles = np.arange(0.0, 360.0, options.angle_step_deg)
        candidates, best = [], -np.inf
        for i, angle in enumerate(angles):
            templ, local_to_templ = rotate_tight(local.image, angle)
            templ = self.blur(templ)
            image, pad = pad_to_fit(self.map_image, templ.shape)
            scores = cv2.matchTemplate(image, templ, self.cv_method)
            if self.cv_method in (cv2.TM_SQDIFF, cv2.TM_SQDIFF_NORMED):
                scores = 1.0 - scores
            scores = np.nan_to_num(scores, nan=-1.0, posinf=-1.0, neginf=-1.0)
            for score, (mx, my) in top_peaks(scores, options.peaks_per_angle, self.peak_radius_px):
                a = translation_px(mx - pad[0], my - pad[1]) @ local_to_templ
                candidates.append(Candidate(pose_from_match(self.map, local, a), float(score)))
                best = max(best, score)
            if progress:
                progress((i + 1) / len(angles), float(best))
        candidates.sort(key=lambda c: -c.score)
        return Match(candidates)


def rotate_tight(image: np.ndarray, angle_deg: float):
    """Rotate `image` by angle_deg (counter-clockwise on screen) about its centre onto a
    canvas just large enough, then crop to the non-zero pixels. Returns the template and
    the 3x3 pixel affine from `image` to it."""
    h, w = image.shape
    a = math.radians(angle_deg)
    c, s = abs(math.cos(a)), abs(math.sin(a))
    new_w, new_h = int(math.ceil(w * c + h * s)) + 2, int(math.ceil(w * s + h * c)) + 2
    center = ((w - 1) / 2.0, (h - 1) / 2.0)
    m = translation_px((new_w - 1) / 2.0 - center[0], (new_h - 1) / 2.0 - center[1]) @ rotation_px(angle_deg, center)
    rotated = cv2.warpAffine(image, m[:2], (new_w, new_h), flags=cv2.INTER_LINEAR)
    ys, xs = np.nonzero(rotated)
    if len(xs) == 0:
        return rotated, m
    x0, y0 = int(xs.min()), int(ys.min())
    return rotated[y0:int(ys.max()) + 1, x0:int(xs.max()) + 1], translation_px(-x0, -y0) @ m


def pad_to_fit(image: np.ndarray, templ_shape):
    """Zero-pad `image` so a template of `templ_shape` fits; returns (padded, (left, top))."""
    th, tw = templ_shape
    h, w = image.shape
    px, py = max(0, tw - w), max(0, th - h)
    if px == 0 and py == 0:
        return image, (0, 0)
    left, top = px // 2 + 1, py // 2 + 1
    return cv2.copyMakeBorder(image, top, py - py // 2 + 1, left, px - px // 2 + 1,
                              cv2.BORDER_CONSTANT, value=0), (left, top)


def top_peaks(scores: np.ndarray, k: int, radius: int):
    """Up to k (score, (x, y)) maxima of `scores`, each at least `radius` apart."""
    scores = scores.copy()
    out = []
    for _ in range(k):
        _, max_val, _, (x, y) = cv2.minMaxLoc(scores)
        if not np.isfinite(max_val):
            break
        out.append((max_val, (x, y)))
        scores[max(0, y - radius):y + radius + 1, max(0, x - radius):x + radius + 1] = -np.inf
    return out


def ccoeff_matcher(occupancy_map):
    return RotatedTemplateMatcher(occupancy_map, cv2.TM_CCOEFF_NORMED, 'template_ccoeff', min_score=0.25, blur=False)


def sqdiff_matcher(occupancy_map):
    return RotatedTemplateMatcher(occupancy_map, cv2.TM_SQDIFF_NORMED, 'template_sqdiff', min_score=0.25, blur=True)
