"""Unknown is not evidence (bnb.unknown_credit, on by default): a return landing on a cell
the map does not know neither explains nor contradicts a place (docs/METHOD.md, "Unknown
cells"). A place whose nearby walls were never mapped stays a rival of its fully mapped
twin, so the twin is never answered confidently; where the map knows every cell a scan
reaches, nothing changes. The twin is named whatever the option; with no credit (0) unknown
counts against a place as free space does, and the twin can win."""
import math

import numpy as np
import pytest

from conftest import grid_map, walled
from global_loc.bench.unmapped import unmapped_around
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.map_io import UNKNOWN, make_map
from global_loc.core.matchers import MatchOptions
from global_loc.core.matchers.bnb import BranchAndBoundOptions
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D, pose_correct
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan


def half_turn_symmetric_hall():
    """An 8 x 4 m hall at 5 cm, symmetric under a half turn about its centre (4, 2): an
    L-shaped counter and a pillar in the left half, the same turned in the right half."""
    grid = walled(80, 160)
    blocks = [(10, 14, 20, 45), (10, 30, 41, 45), (50, 54, 60, 64)]    # rows, cols (y, x)
    for r0, r1, c0, c1 in blocks:
        grid[r0:r1, c0:c1] = 100
        grid[80 - r1:80 - r0, 160 - c1:160 - c0] = 100            # the same block turned by a half turn
    return grid_map(grid)


UNCREDITED = LocalizerConfig(bnb=BranchAndBoundOptions(unknown_credit=0.0))


def twin_of(pose: Rigid2D) -> Rigid2D:
    return Rigid2D(8.0 - pose.x, 4.0 - pose.y, math.remainder(pose.yaw + math.pi, 2 * math.pi))


POSES = [Rigid2D(1.5, 2.5, 0.4), Rigid2D(3.2, 1.0, -1.2), Rigid2D(0.8, 3.2, 2.6)]


# (at 1.2 m the corner pose has over a third of its scan on unknown cells: no rival then, docs/METHOD.md)
@pytest.mark.parametrize('radius', [0.8, 1.0])
@pytest.mark.parametrize('pose', POSES)
def test_a_place_whose_nearby_walls_are_unknown_is_never_answered_at_its_twin(pose, radius):
    hall = half_turn_symmetric_hall()
    scan = simulate_scan(hall, pose,
                         LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(1))
    full = Localizer(hall).localize(scan)
    assert not full.success and full.outcome == Outcome.AMBIGUOUS       # the hall itself: the twin ties
    assert any(pose_correct(h.pose, twin_of(pose)) for h in full.hypotheses)
    assert 'its twin' in full.message, full.message
    cut = unmapped_around(hall, pose, radius)           # the true place's nearby walls never mapped
    assert Localizer(cut, UNCREDITED).localize(scan).outcome != Outcome.NO_MATCH
    result = Localizer(cut).localize(scan)
    assert not (result.success and pose_correct(result.pose, twin_of(pose))), result.message
    assert result.outcome == Outcome.AMBIGUOUS, result.message
    assert any(pose_correct(h.pose, pose) for h in result.hypotheses), result.message
    assert any(pose_correct(h.pose, twin_of(pose)) for h in result.hypotheses), result.message


def test_with_no_credit_for_unknown_cells_the_twin_is_answered_confidently():
    """What the rule prevents: unknown counted against the true place (unknown_credit 0),
    the corner pose's fully mapped twin wins with a confident answer."""
    hall, pose = half_turn_symmetric_hall(), POSES[2]
    scan = simulate_scan(hall, pose, LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(1))
    result = Localizer(unmapped_around(hall, pose, 1.0), UNCREDITED).localize(scan)
    assert result.success and pose_correct(result.pose, twin_of(pose)), result.message


def test_where_the_map_knows_every_cell_the_scan_reaches_the_answer_is_unchanged(office_map):
    """An unknown patch the scan never reaches (a closed-off room's floor made unknown,
    with a door onto the hall) changes neither the answer nor its figures."""
    grid = office_map.occupancy.copy()
    rows, cols = np.nonzero(office_map.free)
    far = (rows < rows.min() + 30) & (cols < cols.min() + 30)       # a corner of the free space
    grid[rows[far], cols[far]] = UNKNOWN
    patched = make_map(grid, office_map.resolution, office_map.origin, 'office with an unknown corner')
    assert patched.open_unknown().any()
    rng = np.random.default_rng(4)
    checked = 0
    for pose in [Rigid2D(x, y, yaw) for x, y, yaw in rng.uniform([1, 1, -3], [25, 17, 3], (40, 3))]:
        col, row = office_map.frame.cell_of(np.array([[pose.x, pose.y]]))[0]
        if not (0 <= row < office_map.height and 0 <= col < office_map.width) or not office_map.free[row, col]:
            continue
        scan = simulate_scan(office_map, pose,
                             LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0), rng=rng)
        a, b = Localizer(office_map).localize(scan), Localizer(patched).localize(scan)
        if not a.success:
            continue
        assert (a.outcome, a.pose, a.score) == (b.outcome, b.pose, b.score), (pose, a.message, b.message)
        checked += 1
        if checked == 3:
            break
    assert checked == 3


def test_a_rival_search_cut_short_says_the_known_cells_were_confident():
    """The node budget that ends the search for rivals on unknown cells (after a confident
    answer on the cells the map knows) is never a success, and the message says which part
    was cut short: on a map mostly unexplored it is the part that costs."""
    hall, pose = half_turn_symmetric_hall(), POSES[2]
    scan = simulate_scan(hall, pose, LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(1))
    cut = unmapped_around(hall, pose, 1.5)
    known_only = Localizer(cut, UNCREDITED).localize(scan)       # the same first search, no rival search
    both = Localizer(cut).localize(scan)                          # the first search and the rival search
    assert known_only.success and both.success, (known_only.message, both.message)
    first, whole = known_only.search_stats.expansions, both.search_stats.expansions
    assert whole > 1.5 * first, (first, whole)
    # halfway through the rival search: the search threads may expand a few nodes more or less
    budget = (first + whole) // 2
    result = Localizer(cut, LocalizerConfig(bnb=BranchAndBoundOptions(max_nodes=budget))).localize(scan)
    assert result.outcome == Outcome.SEARCH_INCOMPLETE and not result.success, result.message
    assert result.message.startswith('search incomplete: confident on what the map knows, but the search for a '
                                     'rival on its unknown cells stopped after'), result.message


def test_a_search_asked_only_for_fits_leaves_out_the_rival_search():
    """MatchOptions.unknown_rivals off (the mirror check's search, which compares fits only):
    the confident first search is the answer, with only its own expansions; on, the rival
    search finds the true place and the answer is not confident."""
    hall, pose = half_turn_symmetric_hall(), POSES[2]
    scan = simulate_scan(hall, pose, LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(1))
    cut = unmapped_around(hall, pose, 1.0)
    bnb, points = Localizer(cut).matcher('bnb'), scan_to_points(scan)
    known_only = Localizer(cut, UNCREDITED).matcher('bnb').match(points, MatchOptions())
    fits = bnb.match(points, MatchOptions(unknown_rivals=False))
    both = bnb.match(points, MatchOptions())
    assert bnb.judge(fits.candidates).success and not bnb.judge(both.candidates).success
    assert fits.stats.expansions < both.stats.expansions
    assert fits.candidates[0].laser_pose == known_only.candidates[0].laser_pose


def test_the_mirror_check_asks_its_search_for_fits_only():
    """The mirror check compares the mirror image's best fit with the scan's: whether the
    mirror image's own answer would be confident is not asked, so its search runs no rival
    search (on real logs that search was a third of the check's time)."""
    from global_loc.core.matchers.mirror import mirror_verdict
    hall, pose = half_turn_symmetric_hall(), POSES[2]
    scan = simulate_scan(hall, pose, LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(1))
    bnb, points = Localizer(unmapped_around(hall, pose, 1.0)).matcher('bnb'), scan_to_points(scan)
    asked = []
    search = bnb.match
    bnb.match = lambda pts, options, progress=None: asked.append(options) or search(pts, options, progress)
    best = search(points, MatchOptions()).candidates[0]
    mirror_verdict(bnb, points, best, MatchOptions(), 1000)
    assert asked and not any(o.unknown_rivals for o in asked)
