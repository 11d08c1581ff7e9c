"""Bad and degenerate input to the core and the CLI (no ROS) ends with a clear error or
an honest outcome, never a crash, a hang or a confident wrong answer. The process-level
cases (signals, a dying server) are in test_shutdown.py."""
import json
import math
import threading

import numpy as np
import pytest
from test_cli import run_cli

from conftest import OFFICE_YAML, grid_map, small_room
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.map_io import MapError, from_occupancy_grid, load_map_yaml
from global_loc.core.matchers import BranchAndBoundOptions, MatchOptions, MethodError, make_matcher, resolve_method
from global_loc.core.matchers.features import surf_available
from global_loc.core.outcome import CanceledError, Outcome
from global_loc.core.scan import Scan, ScanError
from global_loc.core.transform import Rigid2D
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import simulate_scan

METHODS = ('bnb', 'template_ccoeff', 'template_sqdiff', 'features_orb')


def degenerate_scans():
    """Scans with fewer than three distinct points: all ranges 0 with range_min 0 (every
    point at the laser), one finite beam, two points."""
    zeros = Scan(-2.0, 0.01, 0.0, 10.0, np.zeros(400))
    one = np.full(400, np.inf)
    one[200] = 2.0
    two = np.full(400, np.nan)
    two[[10, 300]] = 1.5
    return {'all zero': zeros, 'one beam': Scan(-2.0, 0.01, 0.05, 10.0, one), 'two points':
            Scan(-2.0, 0.01, 0.05, 10.0, two)}


@pytest.mark.parametrize('name', list(degenerate_scans()))
@pytest.mark.parametrize('method', METHODS)
def test_a_scan_without_a_shape_is_a_clear_error_for_every_method(method, name):
    loc = Localizer(load_map_yaml(OFFICE_YAML))
    with pytest.raises(ScanError, match='distinct point'):
        loc.localize(degenerate_scans()[name], method)


def test_distinct_points_are_counted_up_to_three_as_a_full_unique_would():
    from global_loc.core.scan import count_distinct_up_to_3
    rng = np.random.default_rng(0)
    for _ in range(2000):      # few rows over few values: every case of 0 .. 3+ distinct, repeats, order
        rows = rng.integers(0, rng.integers(1, 4), (rng.integers(0, 7), 2)).astype(float)
        assert count_distinct_up_to_3(rows) == min(3, len(np.unique(rows, axis=0)))


def test_a_tie_is_never_a_success_for_any_matcher(office_map):
    """The thesis matchers localized a scan when its best score passed their minimum,
    even tied with the next place (confidence 0)."""
    from global_loc.core.matchers.base import Candidate
    for method in ('template_ccoeff', 'template_sqdiff', 'features_orb'):
        matcher = make_matcher(method, office_map)
        score = matcher.min_score + 1.0
        tie = [Candidate(Rigid2D(1, 1, 0), score), Candidate(Rigid2D(5, 5, 0), score)]
        verdict = matcher.judge(tie)
        assert verdict.outcome == Outcome.AMBIGUOUS and verdict.confidence == 0.0, (method, verdict)
    # bnb's threshold cannot be set to accept a tie
    with pytest.raises(ValueError, match='min_confidence must be in'):
        BranchAndBoundOptions(min_confidence=0.0)


@pytest.mark.parametrize('origin', [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, -math.inf),
                                    ('x', 0.0, 0.0), (0.0, 0.0)])
def test_an_occupancy_grid_with_a_non_finite_or_bad_origin_is_refused(origin):
    with pytest.raises(MapError, match='origin'):
        from_occupancy_grid(4, 4, 0.05, origin, np.zeros(16))


@pytest.mark.process
def test_cli_bad_truth_and_bad_bytes_are_errors_of_their_line_only(tmp_path):
    sim = run_cli('simulate', '--map', OFFICE_YAML, '--count', '1', '--seed', '3')
    good = json.loads(sim.stdout.splitlines()[0])
    lines = [b'\xef\xbb\xbf' + json.dumps(good).encode()]                  # a BOM on line 1
    for truth in ({'x': 1}, 'here', [1, 2, 3], None, {'x': 'a', 'y': 0, 'yaw': 0}, {'x': 1e400, 'y': 0, 'yaw': 0}):
        lines.append(json.dumps({**good, 'truth': truth}).encode())
    lines.append(b'{"angle_min": \xff\xfe}')                                 # not UTF-8
    lines.append(json.dumps(good).encode())
    scans = tmp_path / 'scans.jsonl'
    scans.write_bytes(b'\n'.join(lines) + b'\n')
    out = run_cli('localize', '--map', OFFICE_YAML, '--scans', str(scans))
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(rows) == len(lines)
    assert rows[0]['outcome'] == rows[-1]['outcome'] == 'localized' and 'error_xy' in rows[0]
    assert rows[4]['outcome'] == 'localized' and 'truth' not in rows[4]      # "truth": null is no truth
    for k in (1, 2, 3, 5, 6):
        assert rows[k]['outcome'] == 'unusable_scan' and '"truth" must be' in rows[k]['error'], rows[k]
    assert rows[7]['outcome'] == 'unusable_scan' and 'line 8' in rows[7]['error']


def test_an_obstacle_free_map_says_so_at_once():
    loc = Localizer(grid_map(np.zeros((50, 50), int)))
    scan = Scan(-2.0, 0.01, 0.05, 10.0, np.full(400, 2.0) + np.random.default_rng(0).random(400))
    for method in ('bnb', 'template_ccoeff'):
        result = loc.localize(scan, method)
        assert result.outcome == Outcome.NO_MATCH and 'no obstacles' in result.message, result


@pytest.mark.skipif(surf_available(), reason='this OpenCV build has SURF')
def test_features_surf_without_surf_is_a_method_error_before_any_work():
    with pytest.raises(MethodError, match='SURF is not in this OpenCV build'):
        resolve_method('features_surf')


def test_max_search_s_ends_any_search_as_incomplete():
    m = small_room()
    scan = simulate_scan(m, Rigid2D(1.0, 2.0, 0.3),
                         LaserConfig(270.0, 271, range_max=4.0, noise_std=0.0, dropout=0.0),
                         rng=np.random.default_rng(2))
    loc = Localizer(m, LocalizerConfig(max_search_s=0.0))
    for method, step in (('template_ccoeff', 0.1), ('bnb', None)):
        result = loc.localize(scan, method, step)
        assert result.outcome == Outcome.SEARCH_INCOMPLETE and 'search limit' in result.message, (method, result)
        assert not result.success


def test_a_cancel_does_not_wait_for_a_rotation_of_the_template_matcher():
    """On a large map one matchTemplate call takes about a second; the cancel reaches the
    caller within the matcher's poll, while the rotation it interrupted runs on: measured
    from the cancel, the caller's answer comes in a small part of the rotation's time."""
    import time
    grid = np.zeros((3000, 3000), int)
    grid[::50, :] = 100
    grid[:, ::70] = 100
    m = grid_map(grid)
    matcher = make_matcher('template_ccoeff', m)
    scan = simulate_scan(m, Rigid2D(30.3, 40.1, 0.2),
                         LaserConfig(270.0, 541, range_max=20.0, noise_std=0.0, dropout=0.0),
                         rng=np.random.default_rng(3))
    from global_loc.core.scan import scan_to_points
    cancelled_at = []

    def cancel(fraction, best):
        cancelled_at.append(time.monotonic())
        raise CanceledError()

    before = set(threading.enumerate())
    with pytest.raises(CanceledError):
        matcher.match(scan_to_points(scan), MatchOptions(), cancel)
    answered = time.monotonic()
    workers = set(threading.enumerate()) - before      # the rotation the cancel left running
    for worker in workers:
        worker.join(30.0)
    finished = time.monotonic()
    assert cancelled_at and workers, 'the rotation had finished before the cancel was asked'
    answer_s, rotation_s = answered - cancelled_at[0], finished - cancelled_at[0]
    assert answer_s < 0.25 * rotation_s, (answer_s, rotation_s)


def test_minor_map_yaml_messages_name_the_path_once_and_a_directory_image(tmp_path):
    (tmp_path / 'img').mkdir()
    yml = tmp_path / 'm.yaml'
    yml.write_text('image: img\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.2\n')
    with pytest.raises(MapError) as e:
        load_map_yaml(yml)
    assert str(e.value).count(str(yml)) == 1 and "'occupied_thresh'" in str(e.value)
    yml.write_text('image: img\nresolution: 0.05\norigin: [0, 0, 0]\nfree_thresh: 0.2\noccupied_thresh: 0.6\n')
    with pytest.raises(MapError, match='is a directory'):
        load_map_yaml(yml)
