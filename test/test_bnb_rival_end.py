"""The search for rivals on unknown cells (after a confident answer on what the map knows)
ends once every place the verdict weighs as a rival is found
(peaks.PeakRefiner.rivals_settled): the places not yet scored bound below the last of
them, so the rest of the search could change neither the hypotheses nor the verdict."""
import numpy as np

from global_loc.core.localizer import Localizer
from global_loc.core.map_io import UNKNOWN, make_map
from global_loc.core.matchers.bnb.peaks import PeakRefiner
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


def half_explored(office_map, rng):
    """The office with half its floor made unknown, cell by cell, in every other 2 m wide
    column band: a map mostly explored, with open unknown cells nearly everywhere a scan
    reaches (as a SLAM map of a floor driven through once has them)."""
    grid = office_map.occupancy.copy()
    band = (np.arange(office_map.width) // 40) % 2 == 1
    patch = office_map.free[:, band] & (rng.random((office_map.height, int(band.sum()))) < 0.5)
    grid[:, band] = np.where(patch, UNKNOWN, grid[:, band])
    return make_map(grid, office_map.resolution, office_map.origin, 'office, half of it unexplored')


def test_a_rival_search_ended_by_its_settled_rivals_answers_as_the_whole_search(office_map, monkeypatch):
    rng = np.random.default_rng(3)
    cut = half_explored(office_map, rng)
    ended = []
    settled = PeakRefiner.rivals_settled

    def recorded(self, *args):
        ended.append(settled(self, *args))
        return ended[-1]

    monkeypatch.setattr(PeakRefiner, 'rivals_settled', recorded)
    compared = 0
    for pose in sample_free_poses(office_map, 6, rng, clearance=0.5):
        scan = simulate_scan(office_map, pose, LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                             rng=rng)
        ended.clear()
        early = Localizer(cut).localize(scan)
        if not any(ended):
            continue
        with monkeypatch.context() as whole:      # the same search, never ended that way
            whole.setattr(PeakRefiner, 'rivals_settled', lambda *_: False)
            full = Localizer(cut).localize(scan)
        assert full.search_stats.exact
        assert (early.outcome, early.confidence, early.message) == (full.outcome, full.confidence, full.message)
        assert [(h.pose, h.score) for h in early.hypotheses] == [(h.pose, h.score) for h in full.hypotheses]
        assert early.search_stats.expansions < full.search_stats.expansions
        compared += 1
    assert compared >= 2, 'no scan here had its rival search ended by its settled rivals'
