"""How a localization ended, as a type callers switch on (nav2's action results carry an
error code the same way) instead of testing message prefixes.

The values are the `outcome` constants of global_loc_interfaces/action/Localize; a test
checks that the two agree. The first group is what a matcher's verdict can say; the
second, what only the server can (it never reached or finished the matcher).
"""
from __future__ import annotations

import enum


class Outcome(enum.IntEnum):
    NONE = 0                # not set
    LOCALIZED = 1           # confident: the pose is right
    AMBIGUOUS = 2           # another place matches almost as well; see the hypotheses
    POOR_MATCH = 3          # the map explains too little of the scan
    SEARCH_INCOMPLETE = 4   # the search stopped at its budget: a better place may be unexplored
    NO_MATCH = 5            # the matcher found no pose at all
    BUSY = 10               # another goal is running
    NO_SCAN = 11            # no scan arrived in time
    NO_MAP = 12             # no map loaded
    BAD_GOAL = 13           # unknown method, out-of-range field
    UNUSABLE_SCAN = 14      # malformed scan, or no valid reading
    CANCELED = 15
    INTERNAL_ERROR = 16
    NOT_ACTIVE = 17         # the lifecycle node is not active

    @property
    def label(self) -> str:
        """The lower-case name used in JSON output: 'localized', 'poor_match', ..."""
        return self.name.lower()


class CanceledError(Exception):
    """Raised from a progress callback (or a wait) to abandon a localization."""


class Stage(enum.StrEnum):
    """A goal's stage in its feedback: the `STAGE_*` constants of the Localize action's
    feedback have the same values (a test checks that the two agree)."""
    WAITING_FOR_SCAN = 'waiting_for_scan'
    PREPARING_SCAN = 'preparing_scan'
    MATCHING = 'matching'
    RESOLVING_BY_MOTION = 'resolving_by_motion'
