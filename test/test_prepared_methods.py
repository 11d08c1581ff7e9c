"""A matcher's precomputation happens with the map, never inside a request: the server's
Localizer serves only the methods prepared with it, and a precomputation that would not
fit its memory budget is refused, with the reason, before anything is allocated."""
import tracemalloc

import numpy as np
import pytest

from global_loc.core import limits
from global_loc.core.localizer import Localizer
from global_loc.core.map_io import make_map
from global_loc.core.matchers import MethodError, make_matcher
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan
from global_loc.sim.synthetic_maps import small_room


def big_map(side: int):
    grid = np.zeros((side, side), dtype=np.int8)
    grid[::50, :] = 100                                   # walls, so the map is not empty
    return make_map(grid, 0.05, Rigid2D(), f'{side} x {side}')


def test_a_prepared_localizer_serves_its_methods_and_refuses_the_others_with_the_reason():
    room = small_room()
    localizer = Localizer(room, prepared=('bnb', 'template_ccoeff'))
    assert localizer.prepared() == ['bnb', 'template_ccoeff'] and localizer.unavailable == {}
    built = localizer.matcher('template_ccoeff')
    assert localizer.matcher('template_ccoeff') is built
    scan = simulate_scan(room, Rigid2D(2.0, 2.0, 0.3),
                         LaserConfig(270, 541, range_max=10.0, noise_std=0.0, dropout=0.0))
    with pytest.raises(MethodError, match='features_orb is not prepared on this server .*methods parameter'):
        localizer.localize(scan, method='features_orb')
    assert localizer.prepared() == ['bnb', 'template_ccoeff']      # nothing was built by the request
    # a live reconfiguration shares the prepared matchers and keeps refusing the others
    again = localizer.reconfigured(localizer.config)
    assert again.matcher('template_ccoeff') is built
    with pytest.raises(MethodError, match='not prepared'):
        again.matcher('features_sift')


def test_a_precomputation_over_its_budget_is_refused_before_it_allocates():
    """SIFT on 2100 x 2100 cells would take ~1.1 GB (240 bytes a cell measured at 2000 x
    2000): refused in milliseconds, allocating nothing like it."""
    m = big_map(2100)
    tracemalloc.start()
    with pytest.raises(limits.BudgetError, match=r'features_sift on a 2100 x 2100 map would need about 1\.\d+ GB'):
        make_matcher('features_sift', m)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 1 << 20, peak
    localizer = Localizer(m, prepared=('template_ccoeff', 'features_sift'))
    assert set(localizer.unavailable) == {'features_sift'} and localizer.prepared() == ['template_ccoeff']
    with pytest.raises(MethodError, match='features_sift could not be prepared for this map: .*budget'):
        localizer.matcher('features_sift')


def test_matchers_within_the_budget_still_build_on_first_use_offline():
    localizer = Localizer(small_room())        # the CLI and the benchmark: built when first asked for
    assert localizer.prepared() == []
    assert localizer.matcher('features_orb').name == 'features_orb' and localizer.prepared() == ['features_orb']
