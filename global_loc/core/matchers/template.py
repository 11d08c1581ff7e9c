"""Rotated template matching (thesis §2.4): the local map, rotated in steps of Δα over
360°, slid over the map image with cv2.matchTemplate.

TM_CCOEFF_NORMED scores in [-1, 1], higher better; TM_SQDIFF_NORMED in [0, 1], lower
better, reported here as 1 - value so that every matcher's higher score is better.
"""
from __future__ import annotations

import math
import threading
import time
from functools import partial

import cv2
import numpy as np

from ..limits import check_angle_step, check_budget
from ..local_grid import build_local_grid, soften
from ..pose import pose_from_match, rotation_px, translation_px
from ..transform import normalize_angle
from .base import Candidate, Match, Matcher

# A Candidate with its Rigid2D, as Python objects: what one placement kept costs.
CANDIDATE_BYTES = 512


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
        self.check_local_map_budget(points)
        local = build_local_grid(points, self.map.resolution, options.closing_kernel,
                                 max_range=self.map.diagonal_m)
        self.check_rotation_budget(local.image.shape, options)
        angles = self.angles(options)
        laser = np.array([*local.laser_px, 1.0])
        candidates, best = [], -np.inf
        deadline = time.monotonic() + options.max_search_s - options.spent_s
        stopped = ''
        for i, angle in enumerate(angles):
            if time.monotonic() > deadline:
                stopped = f'{options.max_search_s:g} s search limit reached after {i} of {len(angles)} rotations'
                break
            templ, local_to_templ = rotate_tight(local.image, angle)
            templ = self.blur(templ)
            window, (ox, oy) = self.search_window(templ.shape, (local_to_templ @ laser)[:2], options.region)
            if window.size == 0:     # the prior's disc lies off the map
                continue
            image, pad = pad_to_fit(window, templ.shape)
            scores = run_checked(partial(cv2.matchTemplate, image, templ, self.cv_method),
                                 partial(progress, i / len(angles), float(best)) if progress else None)
            if self.cv_method in (cv2.TM_SQDIFF, cv2.TM_SQDIFF_NORMED):
                scores = 1.0 - scores
            scores = np.nan_to_num(scores, nan=-1.0, posinf=-1.0, neginf=-1.0)
            for score, (mx, my) in top_peaks(scores, options.peaks_per_angle, self.peak_radius_px):
                a = translation_px(mx - pad[0] + ox, my - pad[1] + oy) @ local_to_templ
                candidates.append(Candidate(pose_from_match(self.map, local, a), float(score)))
                best = max(best, score)
            if progress:
                progress((i + 1) / len(angles), float(best))
        candidates.sort(key=lambda c: -c.score)
        return Match(self.distinct(candidates), stopped=stopped)

    def search_resolution(self, points, angle_step_deg: float) -> tuple[float, float]:
        """A pixel in x and in y (its diagonal: a placement is a whole pixel, and a rotation
        up to half a step off shifts it by about one more - measured up to 0.071 m at 5 cm)
        and the rotation step (see base.Matcher)."""
        return math.sqrt(2.0) * self.map.resolution, math.radians(angle_step_deg)

    def check_rotation_budget(self, local_shape, options) -> None:
        """BudgetError before any rotation when the work would not fit the per-goal budget
        (limits.MATCH_BUDGET_BYTES): the angle arrays (eight float64 arrays of one value
        per rotation with a heading prior) and their candidates, and one rotation's
        images - the rotated canvas and its crop and blur (at most (w + h)^2 / 2 pixels
        each, at 45 deg), the search window padded to fit, and four float32 copies of
        its score image. ValueError for an angle step out of limits.ANGLE_STEP_DEG."""
        rotations = math.ceil(360.0 / check_angle_step(options.angle_step_deg))
        h, w = local_shape
        canvas_side = (w + h) / math.sqrt(2.0) + 3
        map_h, map_w = self.map_image.shape
        if options.region is not None and options.region.radius_m > 0:
            reach = 2 * (options.region.radius_m / self.map.resolution + 2)
            map_h, map_w = min(map_h, reach + canvas_side), min(map_w, reach + canvas_side)
        window = (max(map_w, canvas_side) + 2) * (max(map_h, canvas_side) + 2)
        per_rotation = 3 * canvas_side ** 2 + window + 4 * 4 * window
        nbytes = rotations * (8 * 8 + options.peaks_per_angle * CANDIDATE_BYTES) + per_rotation
        check_budget(f'{self.name}: {rotations} rotations of a {w} x {h} local map over a {map_w:.0f} x '
                     f'{map_h:.0f} window', nbytes, 'use a larger angle step, a smaller search region or bnb')

    def angles(self, options) -> np.ndarray:
        """The template's rotations (deg): every angle step over 360 deg, or those within
        the prior's heading window (a rotation by a turns the laser to map yaw origin + a)."""
        angles = np.arange(0.0, 360.0, options.angle_step_deg)
        region = options.region
        if region is None or not 0 < region.yaw_tolerance < math.pi:
            return angles
        off = np.abs(normalize_angle(np.radians(angles) + self.map.origin.yaw - region.center.yaw))
        return angles[off <= region.yaw_tolerance + math.radians(options.angle_step_deg) / 2]

    def search_window(self, templ_shape, laser_in_templ, region):
        """The part of the map image the template's placements may cover when the laser
        must lie in the prior's disc, and its (left, top) offset; the whole image without one."""
        if region is None or region.radius_m <= 0:
            return self.map_image, (0, 0)
        uc, vc = self.map.frame.world_to_pixel([[region.center.x, region.center.y]])[0]
        reach = region.radius_m / self.map.resolution + 1
        th, tw = templ_shape
        h, w = self.map_image.shape
        x0 = int(np.clip(np.floor(uc - reach - laser_in_templ[0]), 0, w))
        y0 = int(np.clip(np.floor(vc - reach - laser_in_templ[1]), 0, h))
        x1 = int(np.clip(np.ceil(uc + reach - laser_in_templ[0]) + tw, x0, w))
        y1 = int(np.clip(np.ceil(vc + reach - laser_in_templ[1]) + th, y0, h))
        return self.map_image[y0:y1, x0:x1], (x0, y0)


def run_checked(work, check, poll_s: float = 0.02):
    """work() in a thread (OpenCV releases the GIL), calling check() every poll_s
    meanwhile: check may raise (CanceledError) and the caller returns at once, leaving the
    thread to finish alone. One rotation's matchTemplate on a 4000^2 map takes over a
    second; a cancel must not wait for it. Not a daemon thread: the interpreter's exit
    waits for it (C++ code still running at exit aborts the process). Without a check,
    work() runs here."""
    if check is None:
        return work()
    box = {}

    def run():
        try:
            box['value'] = work()
        except BaseException as e:     # re-raised in the caller's thread
            box['error'] = e

    thread = threading.Thread(target=run, name='matchTemplate')
    thread.start()
    while True:
        thread.join(poll_s)
        if not thread.is_alive():
            break
        check()
    if 'error' in box:
        raise box['error']
    return box['value']


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
