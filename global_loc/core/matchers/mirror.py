"""The mirror check of a confident answer. A scan whose beams are read the wrong way round
(a driver's angle_increment of the wrong sign, every field still consistent; a laser
mounted upside down and not said) is the mirror image of what the laser saw: nothing in the
message tells it from a real scan, and where the map has a place like the mirror image of
the true one, the mirrored scan fits there and the answer is confident and wrong.

The check: the scan's mirror image (y -> -y in the laser frame) is searched over the map
with the tracker, pruned from the start below the fit that would beat the answer's by the
lead a confident answer needs (MatchOptions.incumbent: only places that come that close are
scored, a fraction of a full search). When the mirror image fits some place better than
the scan fits its best, by that lead, the scan is more likely mirrored than not: not a
success. The check has a node budget of its own (CHECK_MIN_NODES); one that runs out
without finding such a place leaves the answer as the exhaustive search of the scan itself
judged it, and says so in its message. Where the map is mirror symmetric the two fit alike
and the answer stands - the scan alone cannot tell them apart.
Measured on 20 simulated office scans: it refused 3 of the 4 mirrored scans that were
confidently wrong (the fourth sits in a mirror-symmetric spot, its mirror fitting exactly
as well) and none of the 20 real ones.
"""
from __future__ import annotations

import dataclasses
from typing import Optional

from ..outcome import Outcome
from ..scan import ScanPoints
from .base import Candidate, MatchOptions, ProgressFn, Tracker, Verdict


def mirrored(points: ScanPoints) -> ScanPoints:
    """The scan's mirror image in the laser frame (its beams read the other way round)."""
    return dataclasses.replace(points, points=points.points * [1.0, -1.0], no_return_angles=-points.no_return_angles)


# The check's node budget: as many expansions as the search of the scan itself took, and at
# least CHECK_MIN_NODES - where the answer's own fit is low (a real log's partly explained
# view, 0.5) the seeded search prunes little: on Freiburg's corridors an unbounded check ran
# out of 400 000 nodes (3 s) on 4 of 50 scans, finding no mirror place within reach of the
# answer on any; bounded so, the check at most doubles a search.
CHECK_MIN_NODES = 20_000


def mirror_verdict(tracker: Tracker, points: ScanPoints, best: Candidate, options: MatchOptions, searched: int,
                   progress: Optional[ProgressFn] = None) -> tuple[Optional[Verdict], str]:
    """(None, a note) when the scan's mirror image fits no place found better than the scan
    fits `best` (by the lead a confident answer needs) - the note says when the check ran
    out of its budget (`searched`: the expansions the scan's own search took) before it was
    exhaustive; else (the verdict that replaces a success, '')."""
    lead = min(tracker.lead_needed(best.score), 0.5)
    # only a place beating best by the lead matters: one whose refined fit reaches best / (1 - lead)
    # (only fits are compared: whether the mirror image's own answer would be confident is not asked)
    found = tracker.match(mirrored(points), dataclasses.replace(options, incumbent=best.score / (1.0 - lead),
                                                                max_nodes=max(CHECK_MIN_NODES, searched),
                                                                unknown_rivals=False), progress)
    note = (f'mirror image checked in part: {found.stopped}, no better fit found by then' if found.stopped
            else '')
    if not found.candidates:
        return None, note
    rival = found.candidates[0]
    if rival.score <= best.score or rival.score * (1.0 - min(tracker.lead_needed(rival.score), 1.0)) <= best.score:
        return None, note
    p = rival.laser_pose
    return Verdict(Outcome.POOR_MATCH, 0.0, f'poor match: the scan\'s mirror image fits the map better '
                                            f'({rival.score:.3f} at x={p.x:.2f} y={p.y:.2f}, laser frame) than the '
                                            f'scan fits its best ({best.score:.3f}): are its beams read the wrong way '
                                            f'round (the sign of angle_increment, an upside-down laser not set in '
                                            f'laser_roll)?'), ''
