"""In the core: per-goal quantities within their parameters' bounds and
a stated budget, scans whose fields contradict each other, upside-down lasers, priors
tighter than the search's resolution, absurd map resolutions, map paths that are not files."""
import json
import math
import os
import re
import tracemalloc

import numpy as np
import pytest

from conftest import assert_pose_near
from global_loc.core import limits
from global_loc.core.localizer import Localizer
from global_loc.core.map_io import MapError, from_occupancy_grid, load_map_yaml, make_map, save_map_yaml
from global_loc.core.matchers import MatchOptions
from global_loc.core.mount import LaserMount, MountError
from global_loc.core.scan import Scan, ScanError, scan_to_points
from global_loc.core.search_region import SearchRegion
from global_loc.core.transform import Quaternion, Rigid2D, pose_correct
from global_loc.sim.laser import LaserConfig
from global_loc.sim.raycast import raycast_ranges, simulate_scan
from global_loc.sim.synthetic_maps import small_room


def fan(n=181, angle_min=-math.pi / 2, increment=math.pi / 180, angle_max='consistent'):
    """A scan of n beams at 2 m; angle_max as the fields imply, or as given."""
    last = angle_min + (n - 1) * increment
    return Scan(angle_min, increment, 0.05, 10.0, np.full(n, 2.0),
                angle_max=last if angle_max == 'consistent' else angle_max)


# ---- a scan's angle_max must agree with its other fields ----------------------------
def test_a_mirrored_scan_is_refused_with_the_reason():
    """A filter that flipped angle_increment's sign: angle_min -pi/2, angle_max +pi/2, increment < 0."""
    mirrored = Scan(-math.pi / 2, -math.pi / 180, 0.05, 10.0, np.full(181, 2.0), angle_max=math.pi / 2)
    with pytest.raises(ScanError, match='angle_max .* disagrees .* more than one increment'):
        scan_to_points(mirrored)


@pytest.mark.parametrize('off_by_increments', [0.0, 1.0, -1.0, 0.5])
def test_angle_max_within_one_increment_is_accepted(off_by_increments):
    """Drivers differ on whether angle_max is the last beam's angle or one step past it."""
    inc = math.pi / 180
    scan = fan(angle_max=-math.pi / 2 + 180 * inc + off_by_increments * inc)
    assert len(scan_to_points(scan).points) == 181


@pytest.mark.parametrize('angle_max', [math.pi / 2 + 2.5 * math.pi / 180, 0.0, math.nan, math.inf])
def test_angle_max_off_by_more_than_one_increment_or_not_finite_is_refused(angle_max):
    with pytest.raises(ScanError, match='angle_max'):
        scan_to_points(fan(angle_max=angle_max))


def test_angle_max_unknown_is_not_checked_and_survives_json():
    assert len(scan_to_points(fan(angle_max=None)).points) == 181
    assert Scan.from_dict(fan(angle_max=None).to_dict()).angle_max is None
    assert Scan.from_dict(fan().to_dict()).angle_max == pytest.approx(math.pi / 2)
    with pytest.raises(ScanError, match='angle_max'):
        scan_to_points(Scan.from_dict({**fan().to_dict(), 'angle_max': -1.0}))


# ---- absurd map resolutions and sizes refused at load ------------------------------
ABSURD_RESOLUTIONS = [1e-12, 1e-8, 1e-6, 0.0, -0.05, 1e6, math.inf, math.nan]


@pytest.mark.parametrize('resolution', ABSURD_RESOLUTIONS)
def test_an_absurd_resolution_is_refused_from_an_occupancy_grid(resolution):
    with pytest.raises(MapError, match='resolution'):
        from_occupancy_grid(10, 10, resolution, (0.0, 0.0, 0.0), np.zeros(100))


@pytest.mark.parametrize('resolution', ABSURD_RESOLUTIONS)
def test_an_absurd_resolution_is_refused_from_yaml(tmp_path, resolution):
    path = tmp_path / 'm.yaml'
    save_map_yaml(make_map(np.zeros((10, 10), np.int8), 0.05, Rigid2D()), path)
    path.write_text(path.read_text().replace('resolution: 0.05', f'resolution: {resolution}'))
    with pytest.raises(MapError, match='resolution'):
        load_map_yaml(path)


@pytest.mark.parametrize('resolution', [limits.MAP_RESOLUTION_M[0], 0.05, limits.MAP_RESOLUTION_M[1]])
def test_resolutions_within_the_bounds_load(resolution):
    assert from_occupancy_grid(10, 10, resolution, (0.0, 0.0, 0.0), np.zeros(100)).resolution == resolution


def test_a_grid_of_too_many_cells_is_refused_before_its_data_is_read():
    side = int(math.isqrt(limits.MAX_MAP_CELLS)) + 1
    with pytest.raises(MapError, match='cells, more than'):   # data is never touched: its size is wrong too
        from_occupancy_grid(side, side, 0.05, (0.0, 0.0, 0.0), np.zeros(1))


# ---- a map path that is not a regular file says what it is ------------------------
def test_map_yaml_that_is_a_directory_a_symlink_loop_or_a_device_says_so(tmp_path):
    os.symlink(tmp_path / 'b', tmp_path / 'a')
    os.symlink(tmp_path / 'a', tmp_path / 'b')
    os.mkfifo(tmp_path / 'fifo')
    os.symlink(tmp_path / 'nowhere', tmp_path / 'dangling')
    cases = {str(tmp_path): 'is a directory', str(tmp_path / 'a'): 'is a symlink loop',
             '/dev/null': 'is a character device', str(tmp_path / 'fifo'): r'is a FIFO \(named pipe\)',
             str(tmp_path / 'dangling'): "is a symlink to .*nowhere', which does not exist",
             str(tmp_path / 'missing.yaml'): 'not found'}
    for path, says in cases.items():
        with pytest.raises(MapError, match=says):
            load_map_yaml(path)


def test_map_image_that_is_a_fifo_or_a_loop_says_so(tmp_path):
    path = tmp_path / 'm.yaml'
    save_map_yaml(make_map(np.zeros((10, 10), np.int8), 0.05, Rigid2D()), path)
    os.remove(tmp_path / 'm.pgm')
    os.mkfifo(tmp_path / 'm.pgm')
    with pytest.raises(MapError, match=r'image .*m.pgm is a FIFO'):
        load_map_yaml(path)
    os.remove(tmp_path / 'm.pgm')
    os.symlink(tmp_path / 'm.pgm', tmp_path / 'm.pgm')
    with pytest.raises(MapError, match=r'image .*m.pgm is a symlink loop'):
        load_map_yaml(path)


# ---- an upside-down laser -------------------------------------------------------
def test_mount_from_tf_reads_the_x_axis_heading_and_upside_down():
    upright = LaserMount.from_roll_pitch_yaw(0.2, -0.1, 0.0, 0.0, 0.7)
    assert upright == LaserMount(Rigid2D(0.2, -0.1, pytest.approx(0.7)), False)
    flipped = LaserMount.from_roll_pitch_yaw(0.2, -0.1, math.pi, 0.0, 0.7)
    assert flipped.upside_down and flipped.base_T_laser.yaw == pytest.approx(0.7)
    # the same rotation said as pitch pi and a yaw off by pi
    same = LaserMount.from_roll_pitch_yaw(0.2, -0.1, 0.0, math.pi, 0.7 - math.pi)
    assert same.upside_down and same.base_T_laser.yaw == pytest.approx(0.7)
    # a quaternion with roll pi about x, then yaw 0.7: q = qz(0.7) * qx(pi)
    c, s = math.cos(0.35), math.sin(0.35)
    from_q = LaserMount.from_quaternion(0.2, -0.1, Quaternion(c, s, 0.0, 0.0))
    assert from_q.upside_down and from_q.base_T_laser.yaw == pytest.approx(0.7)
    assert LaserMount.from_roll_pitch_yaw(0, 0, math.radians(178), 0, 0).upside_down   # within the tilt bound


@pytest.mark.parametrize('roll, pitch', [(math.radians(30), 0.0), (0.0, math.radians(-10)), (math.pi / 2, 0.0),
                                         (math.pi - math.radians(20), 0.0)])
def test_a_tilted_laser_is_refused_with_the_reason(roll, pitch):
    with pytest.raises(MountError, match='tilted .* out of the horizontal plane'):
        LaserMount.from_roll_pitch_yaw(0.0, 0.0, roll, pitch, 0.3)


def test_upright_negates_every_angle_and_keeps_a_contradiction_visible():
    mount = LaserMount(Rigid2D(), upside_down=True)
    up = mount.upright(fan())
    assert up.angle_min == pytest.approx(math.pi / 2) and up.angle_increment == pytest.approx(-math.pi / 180)
    assert np.allclose(scan_to_points(up).points[:, 1], -scan_to_points(fan()).points[:, 1])
    with pytest.raises(ScanError, match='angle_max'):
        scan_to_points(mount.upright(fan(angle_max=0.0)))
    scan = fan()
    assert LaserMount().upright(scan) is scan


@pytest.mark.parametrize('method', ['bnb', 'template_ccoeff'])
@pytest.mark.parametrize('base', [Rigid2D(2.5, 2.2, -0.6), Rigid2D(3.0, 2.0, 2.5)])
def test_an_upside_down_laser_localizes_right(method, base):
    """The laser 0.25 m ahead of the base, x axis along the base's, upside down: its beam at
    laser angle a points at base heading -a. Read as an upright laser's the scan is the
    room's mirror image; turned upright by its mount it gives the base's pose."""
    room = small_room()
    mount = LaserMount.from_roll_pitch_yaw(0.25, 0.0, math.pi, 0.0, 0.0)
    laser_pose = base * mount.base_T_laser
    upright_scan = simulate_scan(room, laser_pose, LaserConfig(240.0, 481, range_max=8.0, noise_std=0.0, dropout=0.0))
    angles = upright_scan.angles()
    # what the upside-down laser reports: beam i at laser angle angles[i] sees the room at -angles[i]
    raw = Scan(upright_scan.angle_min, upright_scan.angle_increment, upright_scan.range_min,
               upright_scan.range_max, raycast_ranges(room, laser_pose, -angles, 8.0), angle_max=float(angles[-1]))
    localizer = Localizer(room)
    result = localizer.localize(mount.upright(raw), method=method, base_T_laser=mount.base_T_laser)
    assert result.success, result.message
    assert_pose_near(result.pose, base, 0.1, 3.0)
    as_if_upright = localizer.localize(raw, method=method, base_T_laser=mount.base_T_laser)   # the mirror image
    assert as_if_upright.pose is None or not pose_correct(as_if_upright.pose, base)


# ---- a goal's work within the angle step's bounds and a stated budget -------------
@pytest.fixture(scope='module')
def room_scan():
    room = small_room()
    return room, scan_to_points(simulate_scan(room, Rigid2D(2.5, 2.2, -0.6),
                                              LaserConfig(240.0, 481, range_max=8.0, noise_std=0.0, dropout=0.0)))


@pytest.mark.parametrize('step', [1e-3, 0.05, 0.0, -5.0, math.nan, 200.0])
def test_the_template_matcher_refuses_an_angle_step_outside_its_parameters_bounds(room_scan, step):
    """Before: 1e-3 deg ran 360 000 rotations (and 1e-6 built 11-22 GB of angle arrays)."""
    room, points = room_scan
    matcher = Localizer(room).matcher('template_ccoeff')
    with pytest.raises(ValueError, match=r'angle step must be in \[0.1, 180\] degrees'):
        matcher.match(points, MatchOptions(angle_step_deg=step, max_search_s=1.0))
    if step:     # 0 on a goal is the default step
        with pytest.raises(ValueError, match='angle step'):
            Localizer(room).localize_points(points, 'template_ccoeff', angle_step_deg=step)


def test_the_template_matcher_refuses_work_over_the_budget_before_allocating_it(room_scan, monkeypatch):
    room, points = room_scan
    matcher = Localizer(room).matcher('template_ccoeff')
    monkeypatch.setattr(limits, 'MATCH_BUDGET_BYTES', 4 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(limits.BudgetError, match=r'3600 rotations .* more than the per-goal budget of 4 MB'):
            matcher.match(points, MatchOptions(angle_step_deg=0.1))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20       # only the local map was drawn
    assert matcher.match(points, MatchOptions(angle_step_deg=5.0)).candidates   # 72 rotations fit


def test_the_budget_admits_the_finest_step_on_a_real_map(office_map):
    matcher = Localizer(office_map).matcher('template_ccoeff')
    matcher.check_rotation_budget((400, 400), MatchOptions(angle_step_deg=limits.ANGLE_STEP_DEG[0]))


def test_a_local_map_over_the_budget_is_refused_before_it_is_drawn(room_scan, monkeypatch):
    room, points = room_scan
    monkeypatch.setattr(limits, 'MATCH_BUDGET_BYTES', 16 << 10)
    for method in ('features_orb', 'template_ccoeff'):
        with pytest.raises(limits.BudgetError, match='a local map of .* pixels'):
            Localizer(room).matcher(method).match(points, MatchOptions())


# ---- a prior tighter than the search's resolution is searched wider, said; answers lie in it ----
def test_widened_to_says_what_it_widened():
    region = SearchRegion(Rigid2D(1.0, 2.0, 0.5), 0.01, math.radians(0.01))
    wide, said = region.widened_to(0.05, math.radians(1.0))
    assert (wide.center, wide.radius_m, wide.yaw_tolerance) == (region.center, 0.05, pytest.approx(math.radians(1.0)))
    assert said == ("search radius 0.01 m widened to 0.05 m and yaw tolerance 0.01 deg widened to 1 deg, the "
                    "search's resolution, for the search; the answer lies in the prior")
    assert SearchRegion(Rigid2D(), 0.01, 0.0).widened_to(0.05, 0.1) == (SearchRegion(Rigid2D(), 0.05, 0.0),
                                                                        "search radius 0.01 m widened to 0.05 m, "
                                                                        "the search's resolution, for the search; "
                                                                        "the answer lies in the prior")
    loose = SearchRegion(Rigid2D(), 1.0, 0.5)
    assert loose.widened_to(0.05, 0.1) == (loose, '')
    assert SearchRegion(Rigid2D()).widened_to(0.05, 0.1) == (SearchRegion(Rigid2D()), '')   # unbounded stays so


TRUE_POSES = [Rigid2D(2.512, 2.189, -0.6), Rigid2D(1.642, 1.713, 2.385), Rigid2D(2.683, 1.338, 0.349)]


@pytest.mark.parametrize('method', ['bnb', 'template_ccoeff'])
@pytest.mark.parametrize('radius_m, yaw_tolerance_deg, said', [
    (0.01, 0.0, 'search radius 0.01 m widened to'), (0.0, 0.01, 'yaw tolerance 0.01 deg widened to'),
    (0.01, 0.01, 'search radius 0.01 m widened to .* and yaw tolerance 0.01 deg widened to')])
def test_a_prior_tighter_than_the_search_centred_on_the_truth_localizes_and_says_it_was_widened(
        method, radius_m, yaw_tolerance_deg, said):
    """Before: NO_MATCH ("bnb found no pose on free space"), even centred on the true pose."""
    room = small_room()
    localizer = Localizer(room)
    for truth in TRUE_POSES:
        scan = simulate_scan(room, truth,
                             LaserConfig(240.0, 481, range_max=8.0, noise_std=0.01, dropout=0.0),
                             rng=np.random.default_rng(1))
        result = localizer.localize(scan, method, region=SearchRegion(truth, radius_m, math.radians(yaw_tolerance_deg)))
        assert result.success, (truth, result.message)
        assert_pose_near(result.pose, truth, 0.1, 3.0)
        assert re.search(f"{said} .*, the search's resolution, for the search; the answer lies in the prior$",
                         result.message), result.message
        prior = SearchRegion(truth, radius_m, math.radians(yaw_tolerance_deg))
        assert prior.contains(result.pose) and not result.region == prior      # searched wider, answered inside


# ---- a non-finite pose is impossible at the last step; one range per parameter ------------------
@pytest.mark.parametrize('flag', [('--laser-x', 'nan'), ('--laser-y', 'inf'), ('--laser-yaw', 'nan'),
                                  ('--laser-x', '1e9'), ('--bnb-sigma-cells', '0'), ('--bnb-max-points', '0'),
                                  ('--bnb-max-range', '0'), ('--bnb-keep-ratio', 'nan')])
def test_the_cli_refuses_a_laser_or_bnb_flag_outside_the_servers_range(tmp_path, capsys, flag):
    from global_loc.offline.cli import main
    scans = tmp_path / 'scans.jsonl'
    scan = simulate_scan(small_room(), Rigid2D(2.0, 2.0, 0.3),
                         LaserConfig(270, 541, range_max=10.0, noise_std=0.0, dropout=0.0))
    scans.write_text(json.dumps({**scan.to_dict()}) + '\n')
    assert main(['localize', '--map', write_room(tmp_path), '--scans', str(scans), *flag]) == 2
    out, err = capsys.readouterr()
    assert out == '' and re.search(r'error: .*must be in \[', err), err


def write_room(tmp_path) -> str:
    path = str(tmp_path / 'room.yaml')
    save_map_yaml(small_room(), path)
    return path


def test_a_result_refuses_a_non_finite_pose_whichever_way_it_is_given():
    from global_loc.core.localizer import Hypothesis, LocalizationResult, NonFinitePose
    from global_loc.core.outcome import Outcome
    nan = Rigid2D(float('nan'), 0.0, 0.0)
    with pytest.raises(NonFinitePose):
        LocalizationResult(Outcome.LOCALIZED, 'localized', 'bnb', pose=nan)
    result = LocalizationResult(Outcome.LOCALIZED, 'localized', 'bnb', pose=Rigid2D(1.0, 2.0, 0.5))
    with pytest.raises(NonFinitePose):
        result.pose = Rigid2D(0.0, float('inf'), 0.0)
    with pytest.raises(NonFinitePose):
        Hypothesis(Rigid2D(0.0, 0.0, float('nan')), 1.0)
    assert result.pose == Rigid2D(1.0, 2.0, 0.5)


@pytest.mark.parametrize('method', ['bnb', 'template_ccoeff'])
def test_a_non_finite_laser_mounting_is_an_unusable_scan_not_a_nan_pose(method):
    room = small_room()
    scan = simulate_scan(room, Rigid2D(2.0, 2.0, 0.3),
                         LaserConfig(270, 541, range_max=10.0, noise_std=0.0, dropout=0.0))
    for mount in (Rigid2D(float('nan'), 0.0, 0.0), Rigid2D(0.0, 0.0, float('inf'))):
        with pytest.raises(MountError, match='must be finite'):
            Localizer(room).localize(scan, method=method, base_T_laser=mount)


@pytest.mark.ros      # imports the server's parameter table (rclpy)
def test_the_servers_bnb_ranges_are_the_options_own_and_a_tilted_laser_roll_is_refused():
    from global_loc.core.matchers.bnb.options import option_fields, option_range
    from global_loc.ros.parameters import BY_NAME, ConfigError, build_config
    assert all(BY_NAME[f'bnb.{name}'].range == option_range(name) for name, *_ in option_fields())
    defaults = {name: spec.default for name, spec in BY_NAME.items()}
    for roll in (0.0, math.pi, -math.pi, math.radians(4.0)):
        build_config({**defaults, 'laser_roll': roll})
    for roll in (0.5, math.pi / 2, math.pi - 0.3):
        with pytest.raises(ConfigError, match='laser_roll: the laser is tilted'):
            build_config({**defaults, 'laser_roll': roll})


@pytest.mark.ros      # imports the server's parameter table (rclpy)
def test_a_map_set_the_server_cannot_serve_fails_configure_naming_the_parameter():
    """Two maps of one name, a map set with use_map_topic, a served_map not in the set: each
    a ConfigError naming its parameter (configure fails, the node says why; a live
    served_map set is refused the same way through check_set)."""
    from global_loc.ros.parameters import BY_NAME, ConfigError, build_config
    defaults = {name: spec.default for name, spec in BY_NAME.items()}
    good = build_config({**defaults, 'maps': ['f1=/m/a.yaml', 'f2=/m/a.yaml'], 'served_map': 'f2'})
    assert good.map_files == {'f1': '/m/a.yaml', 'f2': '/m/a.yaml'} and good.served_map == 'f2'
    alone = build_config(defaults)
    assert alone.map_files == {'office': alone.map_yaml} and alone.served_map == 'office'
    refused = (({'maps': ['/m/office.yaml', 'office=/n/b.yaml']}, 'parameter maps: two maps named office'),
               ({'maps': ['/m/a.yaml'], 'use_map_topic': True}, 'parameter maps: a map set is read from files'),
               ({'maps': ['/m/a.yaml'], 'served_map': 'b'}, 'parameter served_map: b is not a map of the set'),
               ({'served_map': 'b'}, 'parameter served_map: b is not a map of the set'))
    for values, said in refused:
        with pytest.raises(ConfigError, match=re.escape(said)):
            build_config({**defaults, **values})
