"""Which map am I on: a map set localizes on the right map, says which, and is ambiguous -
never confident - where two maps hold the same place (identical floors)."""
import numpy as np
import pytest

from conftest import OFFICE_YAML, assert_pose_near, seeded_office_scans
from global_loc.core.localizer import Localizer
from global_loc.core.map_io import load_map_yaml, make_map
from global_loc.core.map_set import MapSet, MapSetError, MapSetPrior, map_name, named_paths
from global_loc.core.outcome import Outcome
from global_loc.core.scan import scan_to_points
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import sample_free_poses, simulate_scan


@pytest.fixture(scope='module')
def office_and_mirror():
    """The office and its mirror image (a different building: no scan fits both but at a
    mirror-symmetric spot), each with its Localizer; and 6 seeded office scans."""
    office, scans = seeded_office_scans(6)
    mirror = make_map(np.flipud(office.occupancy).copy(), office.resolution, office.origin, 'mirror')
    return Localizer(office), Localizer(mirror), scans


def test_a_scan_is_localized_on_its_own_map_and_the_answer_names_it(office_and_mirror):
    office, mirror, scans = office_and_mirror
    rng = np.random.default_rng(3)
    maps = MapSet({'mirror': mirror, 'office': office})
    confident = 0
    for scan, truth in scans:
        alone, result = office.localize(scan), maps.localize(scan)
        assert result.map == 'office' and result.hypotheses[0].map == 'office', result.message
        assert result.success == alone.success, result.message     # the mirror adds no doubt, nor certainty
        if result.success:
            confident += 1
            assert_pose_near(result.pose, truth)
            assert '(map office;' in result.message
    assert confident >= 4
    for pose in sample_free_poses(mirror.map, 3, rng, clearance=0.6):        # and one on the other map
        result = maps.localize(simulate_scan(mirror.map, pose,
                                             LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.0),
                                             rng=rng))
        assert result.success and result.map == 'mirror', result.message
        assert_pose_near(result.pose, pose)


def test_identical_floors_are_ambiguous_with_a_hypothesis_on_each_and_the_prior_settles_it(office_and_mirror):
    office, _, scans = office_and_mirror
    floors = MapSet({'floor_1': office, 'floor_2': office})
    for scan, truth in scans[:3]:
        result = floors.localize(scan)
        assert result.outcome == Outcome.AMBIGUOUS and result.confidence < 0.5, result.message
        assert 'ambiguous between maps' in result.message
        assert {h.map for h in result.hypotheses[:2]} == {'floor_1', 'floor_2'}
        settled = floors.localize(scan, prior=MapSetPrior(maps=['floor_2']))        # a prior names the floor
        assert settled.success and settled.map == 'floor_2'
        assert_pose_near(settled.pose, truth)


def test_one_map_answers_as_its_localizer_does(office_and_mirror):
    office, _, scans = office_and_mirror
    scan, _ = scans[0]
    alone, in_set = office.localize(scan), MapSet({'office': office}).localize(scan)
    assert (in_set.outcome, in_set.pose, in_set.confidence, in_set.map) == (alone.outcome, alone.pose,
                                                                            alone.confidence, 'office')


def test_a_map_searched_on_from_its_probe_answers_as_a_map_searched_afresh(office_and_mirror):
    """A map set's probe rounds stop each map's search at a few hundred expansions; its
    search then goes on from where the probe stopped instead of starting again. The
    answer is the one a fresh search gives: the same hypotheses, scores and verdict."""
    office, _, scans = office_and_mirror
    for scan, _ in scans[:3]:
        points = scan_to_points(scan)
        fresh = office.localize_points(points)
        leaf, done = office.probe(points, 300)
        assert not done and 0.0 < leaf <= fresh.search_stats.best_leaf
        resumed = office.localize_points(points)
        assert [(h.pose, h.score) for h in resumed.hypotheses] == [(h.pose, h.score) for h in fresh.hypotheses]
        assert (resumed.outcome, resumed.confidence, resumed.message) == (fresh.outcome, fresh.confidence,
                                                                          fresh.message)


def test_a_map_set_names_its_errors():
    office = Localizer(load_map_yaml(OFFICE_YAML))
    with pytest.raises(MapSetError, match='at least one map'):
        MapSet({})
    with pytest.raises(MapSetError, match=r'no map named floor_9 in the set \(maps: office\)'):
        MapSet({'office': office}).searched(['floor_9'])
    assert map_name('/maps/floor_2.yaml') == 'floor_2' and map_name('office') == 'office'


def test_map_entries_are_named_by_their_name_or_their_file(tmp_path):
    """The CLI's --map and the server's maps read one way: NAME=PATH, a plain path (named by
    its file), an existing file whose name holds '=' (a path), and two of one name refused."""
    odd = tmp_path / 'a=b.yaml'
    odd.write_text('')
    assert named_paths(['floor_2=/m/f.yaml', '/m/office.yaml', str(odd)]) == {
        'floor_2': '/m/f.yaml', 'office': '/m/office.yaml', 'a=b': str(odd)}
    with pytest.raises(MapSetError, match='two maps named office'):
        named_paths(['/m/office.yaml', 'office=/n/other.yaml'])


def test_a_map_set_file_stands_for_the_maps_it_lists(tmp_path):
    """One YAML listing the maps (PATH, NAME=PATH or NAME: PATH, relative to the file) is
    the same as listing them one by one; a bad list, or a name twice across files, is refused."""
    (tmp_path / 'floors').mkdir()
    listing = tmp_path / 'floors' / 'building.yaml'
    listing.write_text('maps:\n  - floor_1: f1.yaml\n  - floor_2=/abs/f2.yaml\n  - ../lobby.yaml\n')
    folder = str(tmp_path / 'floors')
    assert named_paths([str(listing)]) == {'floor_1': f'{folder}/f1.yaml', 'floor_2': '/abs/f2.yaml',
                                           'lobby': f'{folder}/../lobby.yaml'}
    assert named_paths([str(listing), '/m/office.yaml'])['office'] == '/m/office.yaml'
    with pytest.raises(MapSetError, match='two maps named floor_1'):
        named_paths([str(listing), 'floor_1=/m/other.yaml'])
    bad = tmp_path / 'bad.yaml'
    for text, says in (('maps: []\n', 'non-empty list'), ('maps:\n  - 3\n', 'an entry of `maps`')):
        bad.write_text(text)
        with pytest.raises(MapSetError, match=says):
            named_paths([str(bad)])
    assert named_paths([OFFICE_YAML]) == {'office': OFFICE_YAML}       # a map YAML is a map


def test_the_time_limit_is_one_for_the_goal_not_one_per_map(office_and_mirror):
    """max_search_s bounds the goal: on four maps, a search that would take the whole limit
    on each ends at about one limit, not four, and says it stopped there."""
    import dataclasses
    office, _, scans = office_and_mirror
    limit = 0.5
    slow = office.reconfigured(dataclasses.replace(office.config, max_search_s=limit))
    floors = MapSet({f'floor_{i}': slow for i in range(4)})
    result = floors.localize(scans[0][0], method='template_ccoeff', angle_step_deg=1.0)
    assert result.outcome == Outcome.SEARCH_INCOMPLETE, result.message
    assert 'search limit' in result.message, result.message
    assert result.time_s < 2.5 * limit, result.time_s      # four limits would be 2 s and more


def coarser(occupancy_map, name: str):
    """The map drawn again at twice its cell size (a cell occupied where any of its four was,
    free where all were): the same building mapped at another resolution."""
    from global_loc.core.transform import Rigid2D
    g = occupancy_map.occupancy
    h, w = g.shape[0] // 2 * 2, g.shape[1] // 2 * 2
    blocks = g[:h, :w].reshape(h // 2, 2, w // 2, 2)
    out = np.full((h // 2, w // 2), -1, np.int8)
    out[(blocks == 0).all(axis=(1, 3))] = 0
    out[(blocks >= 65).any(axis=(1, 3))] = 100
    o = occupancy_map.origin       # the rows left out were the bottom ones: the corner moves up
    return make_map(out, 2 * occupancy_map.resolution, Rigid2D(o.x, o.y + (g.shape[0] - h) * occupancy_map.resolution,
                                                            o.yaw), name)


def test_identical_floors_at_different_resolutions_are_ambiguous_and_other_floors_still_decide(office_and_mirror):
    """A floor mapped at 0.10 m beside the same floor at 0.05 m: the coarser map's field is
    twice as wide in metres, so by their own scores one copy can lead the other; compared
    on a common footing (MapSet.common_fits) no scan is answered on either. A different
    building at the coarser resolution is still told apart."""
    office, mirror, _ = office_and_mirror
    same = MapSet({'floor_1': office, 'floor_2': Localizer(coarser(office.map, 'floor_2'))})
    other = MapSet({'floor_1': office, 'mirror': Localizer(coarser(mirror.map, 'mirror'))})
    rng = np.random.default_rng(7)
    told_apart = 0
    for truth in sample_free_poses(office.map, 12, rng, clearance=0.4):
        scan = simulate_scan(office.map, truth,
                             LaserConfig(270, 541, range_max=20.0, noise_std=0.01, dropout=0.02), rng=rng)
        result = same.localize(scan)
        assert not result.success, (truth, result.map, result.message)
        assert {h.map for h in result.hypotheses} == {'floor_1', 'floor_2'} or result.outcome != Outcome.AMBIGUOUS
        decided = other.localize(scan)
        assert not decided.success or decided.map == 'floor_1', (truth, decided.message)
        if decided.success:
            assert_pose_near(decided.pose, truth)
            told_apart += 1
    assert told_apart >= 8
