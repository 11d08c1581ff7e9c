"""Matchers by name. Each is built once per map and reused (see base.Matcher)."""
from __future__ import annotations

from typing import Optional

from ..limits import check_build_budget
from .base import Candidate, Match, Matcher, MatchOptions, MethodError, Tracker
from .bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from .features import FeatureMatcher, make_detector
from .scan_features import ScanFeatureMatcher
from .template import ccoeff_matcher, sqdiff_matcher

# The thesis's feature path, one matcher per OpenCV detector (make_detector names them).
DETECTOR_METHODS = {f'features_{d}': d for d in ('orb', 'sift', 'akaze', 'surf')}
_FACTORIES = {
    'bnb': BranchAndBoundMatcher,
    'template_ccoeff': ccoeff_matcher,
    'template_sqdiff': sqdiff_matcher,
    **{name: (lambda m, d=detector: FeatureMatcher(m, d)) for name, detector in DETECTOR_METHODS.items()},
    'features': ScanFeatureMatcher,
}
# The matcher that tracks (core.motion, the health watch) and checks a proposing matcher's
# answer on the map (verify.py) when the configured one is not a Tracker. The thesis
# matchers score images of a whole scan, not one scan at a given pose; tracking scores every
# scan at every hypothesis and searches the whole map about once a second while the robot
# moves, which bnb's precomputed field does in milliseconds; its verdict is exhaustive.
TRACKER_METHOD = 'bnb'


def method_names() -> list[str]:
    return sorted(_FACTORIES)


def resolve_method(name: str) -> str:
    """Canonical matcher name for `name`; MethodError for an unknown one."""
    if name not in _FACTORIES:
        raise MethodError(f'unknown method {name!r}; known: {", ".join(method_names())}')
    if name in DETECTOR_METHODS:
        make_detector(DETECTOR_METHODS[name])     # MethodError when this OpenCV build lacks it (SURF, AKAZE)
    return name


# Peak bytes a thesis matcher's precomputation allocates per map cell (peak RSS measured at
# 2000 x 2000: templates and ORB 9, SIFT 236; SURF's Hessian pyramid and AKAZE's nonlinear
# scale space are float images per level as SIFT's: counted alike, not measured - this
# OpenCV build has neither). features: its kept descriptors capped at 56 a cell
# (scan_features.DESCRIPTOR_BYTES_PER_CELL), twice while FLANN merges its copy, the distance field 4,
# and a view's transient arrays, ~25 MB whatever the map: docs/decisions/0021 has the peaks measured).
BUILD_BYTES_PER_CELL = {'template_ccoeff': 16, 'template_sqdiff': 16, 'features_orb': 24, 'features_sift': 256,
                        'features_akaze': 256, 'features_surf': 256,
                        'features': 128}


def make_matcher(name: str, occupancy_map, bnb_options: Optional[BranchAndBoundOptions] = None) -> Matcher:
    """The matcher `name` built for `occupancy_map` (bnb with `bnb_options`); BudgetError,
    before anything is allocated, when a thesis matcher's precomputation would not fit
    limits.BUILD_BUDGET_BYTES."""
    name = resolve_method(name)
    if name == 'bnb':
        return BranchAndBoundMatcher(occupancy_map, bnb_options)
    cells = occupancy_map.width * occupancy_map.height
    check_build_budget(f'{name} on a {occupancy_map.width} x {occupancy_map.height} map',
                       BUILD_BYTES_PER_CELL[name] * cells, 'use bnb, or template matching, on a map this size')
    return _FACTORIES[name](occupancy_map)


__all__ = ['TRACKER_METHOD', 'BranchAndBoundOptions', 'Candidate', 'Match', 'Matcher', 'MatchOptions', 'MethodError',
           'Tracker', 'make_matcher', 'method_names', 'resolve_method']
