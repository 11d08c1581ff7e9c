"""SearchStats.top_in_band: the top nodes an exhaustive search must expand (those bounded
within the final best's band) - the benchmark's lower limit on a search's expansions."""
import numpy as np

from global_loc.core.localizer import Localizer
from global_loc.core.matchers import MatchOptions
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan


def test_an_exhaustive_search_expands_every_top_node_in_its_band(office_map):
    scan = simulate_scan(office_map, Rigid2D(3.0, 4.0, 0.7),
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                         rng=np.random.default_rng(7))
    stats = Localizer(office_map).matcher('bnb').match(scan_to_points(scan), MatchOptions()).stats
    assert stats.exact
    assert 0 < stats.top_in_band < stats.top_nodes
    # every top node within the band is expanded (a top node is expanded at most once), and
    # the ones below it are not: the top level's expansions are exactly the count
    assert stats.per_level[-1] == stats.top_in_band
