"""Matchers by name. Each is built once per map and reused (see base.Matcher)."""
from __future__ import annotations

from typing import Optional

from .base import Candidate, Match, Matcher, MatchOptions, MethodError
from .bnb import BranchAndBoundMatcher, BranchAndBoundOptions
from .features import FeatureMatcher, make_detector, surf_available
from .template import ccoeff_matcher, sqdiff_matcher

_FACTORIES = {
    'bnb': BranchAndBoundMatcher,
    'template_ccoeff': ccoeff_matcher,
    'template_sqdiff': sqdiff_matcher,
    'features_orb': lambda m: FeatureMatcher(m, 'orb'),
    'features_sift': lambda m: FeatureMatcher(m, 'sift'),
    'features_akaze': lambda m: FeatureMatcher(m, 'akaze'),
    'features_surf': lambda m: FeatureMatcher(m, 'surf'),
}
# 'features' is the thesis's choice where the build has it (SURF), ORB otherwise.
ALIASES = {'features': lambda: 'features_surf' if surf_available() else 'features_orb'}


def method_names() -> list[str]:
    return sorted(_FACTORIES) + sorted(ALIASES)


def resolve_method(name: str) -> str:
    """Canonical matcher name for `name`; MethodError for an unknown one."""
    if name in ALIASES:
        return ALIASES[name]()
    if name not in _FACTORIES:
        raise MethodError(f'unknown method {name!r}; known: {", ".join(method_names())}')
    if name.startswith('features_'):
        make_detector(name.split('_', 1)[1])     # MethodError when this OpenCV build lacks it (SURF, AKAZE)
    return name


def make_matcher(name: str, occupancy_map, bnb_options: Optional[BranchAndBoundOptions] = None) -> Matcher:
    """The matcher `name` built for `occupancy_map` (bnb with `bnb_options`)."""
    name = resolve_method(name)
    if name == 'bnb':
        return BranchAndBoundMatcher(occupancy_map, bnb_options)
    return _FACTORIES[name](occupancy_map)


__all__ = ['BranchAndBoundOptions', 'Candidate', 'Match', 'Matcher', 'MatchOptions', 'MethodError', 'make_matcher',
           'method_names', 'resolve_method']
