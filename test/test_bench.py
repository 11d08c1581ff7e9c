"""The benchmark harness end to end on a tiny run (real matchers, real report)."""
import json
import os
import subprocess
import sys

import pytest

from conftest import needs_pybullet
from global_loc.bench.tables import read_rows

pytestmark = needs_pybullet      # the benchmark's suites simulate with pybullet


def run_bench(out, *args) -> list[dict]:
    """`python -m global_loc.bench --quick ARGS --out OUT`: its rows (it must succeed)."""
    done = subprocess.run([sys.executable, '-m', 'global_loc.bench', '--quick', *args, '--out', str(out)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return read_rows(str(out))


@pytest.mark.process
def test_bench_writes_rows_report_and_plots(tmp_path):
    rows = run_bench(tmp_path, '--suites', 'cut', '--poses', '5', '--methods', 'template_ccoeff,features_orb',
                     '--jobs', '2')
    # 1 pose x 3 radii x 2 maps; template at Δα 5 and 15, ORB once (Δα does not apply to it)
    assert {r['method'] for r in rows} == {'template_ccoeff', 'features_orb'}
    assert all({'ok', 'ok_loose', 'time_s', 'success'} <= set(r) for r in rows)
    assert any(r['ok'] for r in rows if r['method'] == 'template_ccoeff')
    report, details = (tmp_path / 'REPORT.md').read_text(), (tmp_path / 'DETAILS.md').read_text()
    assert 'Suite 1: local maps cut from the map' in details and '| cores |' in report
    assert 'time / baseline' in report and 'git_commit' in report and '[DETAILS.md](DETAILS.md)' in report
    assert (tmp_path / 'cut_time_vs_size.png').stat().st_size > 5000


def test_search_share_table_splits_bnb_time_into_the_search_and_the_rest():
    from global_loc.bench.report import search_share_table
    rows = [{'method': 'bnb', 'cond': 'a', 'time_s': t, 'search_s': s} for t, s in ((0.02, 0.015), (0.04, 0.03),
                                                                                  (0.03, 0.01))]
    rows += [{'method': 'template_ccoeff', 'cond': 'a', 'time_s': t, 'ok': True, 'ok_loose': True, 'success': True}
             for t in (0.5, 0.8, 1.0)]
    table = search_share_table(rows, lambda r: r['cond'], 'condition').splitlines()
    # medians: total 0.03, search 0.015, rest 0.01 (of 0.005, 0.01, 0.02), share 25% (of 25, 25, 67%);
    # baseline 0.8, its 1% 0.008
    assert table[2] == '| a | 3 | 0.030 | 0.015 | 0.010 | 25% | 0.800 | 0.008 |'
    assert search_share_table([r for r in rows if r['method'] != 'bnb'], lambda r: r['cond'], 'condition') == ''


def test_the_report_opens_with_one_line_per_suite_against_the_thesis_method():
    from global_loc.bench.summary import summary_section, thesis_section

    def row(method, ok, success, t, **kw):
        return {'suite': 'cut', 'method': method, 'ok': ok, 'ok_loose': ok, 'success': success, 'time_s': t, **kw}
    rows = [row('bnb', True, True, 0.01), row('bnb', True, True, 0.03), row('bnb', False, False, 0.02),
            row('template_ccoeff', True, True, 1.0, raw_success=True, raw_ok=True),
            row('template_ccoeff', False, True, 2.0),                    # no raw verdict (nothing was checked)
            row('template_ccoeff', False, False, 3.0, raw_success=True, raw_ok=False),   # the check refused it
            row('template_ccoeff', True, True, 9.0, angle_step=15)]      # the thesis method's variant: left out
    lines = summary_section(rows)
    assert lines[0] == '## Summary'
    line = next(x for x in lines if x.startswith('| cut |'))
    # bnb: 2 of 3 right, none confidently wrong, median 0.02; thesis raw: 1 of 3 right, 2 confidently wrong;
    # checked: 1 of 3 right, 1 confidently wrong, median 2.0
    assert line.endswith('| 3 | 67% | 0% | 0.020 | 0.029 | 3 | 33% | 67% | 33% | 33% | 2.00 | 2.90 | 100× |'), line
    thesis = thesis_section(rows)
    assert '| cut | template_ccoeff | 3 | 33% | 67% | 33% | 33% | 2.00 | 2.90 |' in thesis, thesis


def test_the_thesis_section_gives_each_proposers_build_per_map():
    from global_loc.bench.summary import thesis_section
    rows = [{'suite': 'sim', 'map': 'office', 'method': 'features', 'ok': True, 'ok_loose': True, 'success': True,
             'time_s': 0.1, 'build_s': 1.8, 'build_mb': 5.4, 'map_cells': 187200},
            {'suite': 'sim', 'map': 'office', 'method': 'features', 'ok': True, 'ok_loose': True, 'success': True,
             'time_s': 0.1},                                   # built before: no figures of its own
            {'suite': 'sim', 'map': 'office', 'method': 'features_orb', 'ok': False, 'ok_loose': False,
             'success': False, 'time_s': 0.01, 'build_s': 0.01, 'build_mb': None, 'map_cells': 187200}]
    lines = thesis_section(rows)
    assert '| office | features | 0.19 M | 1.80 | 5.4 | 29 |' in lines, lines
    assert '| office | features_orb | 0.19 M | 0.01 | – | – |' in lines, lines


@pytest.mark.process
def test_the_report_is_written_again_from_its_rows_without_running_anything(tmp_path):
    import shutil
    out = tmp_path / 'run'
    shutil.copytree(os.path.join(os.path.dirname(__file__), '..', 'benchmarks', 'results', 'changed'), out)
    (out / 'meta.json').write_text(json.dumps({'machine': {'cpu': 'x'}, 'command': 'python -m global_loc.bench',
                                               'jobs': 1, 'threads': 1, 'wall_time_s': 1.0, 'quick': False,
                                               'maps': {}}))
    done = subprocess.run([sys.executable, '-m', 'global_loc.bench', '--report-only', '--out', str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    report = (out / 'REPORT.md').read_text()
    assert report.index('## Summary') < report.index('Command:') < report.index('What it means:')
    assert '## Changed world' in (out / 'DETAILS.md').read_text()
    assert '| changed |' in report and 'localizations in' not in done.stdout


@pytest.mark.process
def test_changed_world_suite_reports_each_level_with_a_plot(tmp_path):
    rows = run_bench(tmp_path, '--suites', 'changed', '--poses', '1', '--methods', 'bnb', '--jobs', '1')
    assert sorted({r['change'] for r in rows}) == [0, 1, 2, 3] and all('expansions' in r for r in rows)
    details = (tmp_path / 'DETAILS.md').read_text()
    assert '## Changed world' in details and '| bnb | 3 |' in details
    assert (tmp_path / 'changed.png').stat().st_size > 5000


def test_a_changed_world_differs_from_its_map_more_at_each_level_and_never_at_the_robot():
    import numpy as np

    from global_loc.core.map_io import load_map_yaml
    from global_loc.core.paths import default_map_yaml
    from global_loc.core.transform import Rigid2D
    from global_loc.sim.changes import ROBOT_CLEARANCE_M, changed_world
    office = load_map_yaml(default_map_yaml())
    robot = Rigid2D(20.675, 5.225, 0.0)
    changed = [(changed_world(office, level, robot, np.random.default_rng(1)).occupancy != office.occupancy).sum()
               for level in (1, 2, 3)]
    assert 0 < changed[0] < changed[1] < changed[2]
    world = changed_world(office, 3, robot, np.random.default_rng(1))
    col, row = office.frame.cell_of(np.array([[robot.x, robot.y]]))[0]
    rows, cols = np.ogrid[:office.height, :office.width]
    at_robot = np.hypot(cols - col, rows - row) * office.resolution <= ROBOT_CLEARANCE_M
    assert (world.occupancy[at_robot] == office.occupancy[at_robot]).all()


def test_isolated_env_picks_a_dds_domain_no_process_here_uses():
    """Several test and benchmark runs at once: a domain another run's server is on would
    mix the two (seen: the fault suite's goals answered `not_active` by another run's server)."""
    import socket

    processes = pytest.importorskip('global_loc.testing.processes')
    free = max(d for d in processes.DOMAINS if d not in processes.domains_in_use())
    held = []
    try:
        for d in processes.DOMAINS:        # a socket in every other domain's port range
            if d != free:
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                held.append(s)
                try:
                    s.bind(('127.0.0.1', processes.PORT_BASE + processes.DOMAIN_GAIN * d + 240))
                except OSError:            # taken: that domain is in use anyway
                    pass
        assert {processes.isolated_env()['ROS_DOMAIN_ID'] for _ in range(5)} == {str(free)}
    finally:
        for s in held:
            s.close()


def fault_row(scenario, **figures):
    row = {'suite': 'faults', 'scenario': scenario, 'goals': 10, 'answered': 10, 'poses': 8, 'wrong_poses': 0,
           'unchecked_poses': 0, 'wrong_results': 0, 'hangs': 0, 'tracebacks': 0, 'recovery_s': 1.0, 'error': None}
    return {**row, **figures}


def test_the_fault_table_is_built_from_the_runs_rows_per_scenario_and_in_all():
    from global_loc.bench.sections import faults_section
    rows = [fault_row('laser_late', recovery_s=2.0), fault_row('laser_late', recovery_s=4.0, goals=12, answered=11,
                                                               hangs=1),
            fault_row('map_republished', wrong_poses=1, recovery_s=None, crashes=1, outlived=2, nonfinite_poses=1,
                      cancel_max_s=0.25)]
    table = [line for line in faults_section(rows) if line.startswith('| ')]
    assert table[1] == ('| laser_late | 2 | 21 of 22 | 16 | 0 | 0 | 1 | 2 of 2 | 3.00 / 4.00 | 0 | 0 '
                        '| 0 | 0 | 0 | 0.00 |')
    assert table[2] == ('| map_republished | 1 | 10 of 10 | 8 | 1 | 0 | 0 | 0 of 1 | – / – | 0 | 0 '
                        '| 1 | 2 | 1 | 0.25 |')
    assert table[3] == ('| **all** | 3 | 31 of 32 | 24 | **1** | 0 | **1** | 2 of 3 | 3.00 / 4.00 | 0 | 0 '
                        '| **1** | **2** | **1** | 0.25 |')


@pytest.mark.ros
def test_a_fault_scenario_runs_against_real_processes_and_writes_its_table(tmp_path):
    """One run of laser_late (the simulator started 2-6 s after the server, goals all along)."""
    rows = run_bench(tmp_path, '--suites', 'faults', '--fault-scenarios', 'laser_late')
    assert [r['scenario'] for r in rows] == ['laser_late'] and rows[0]['error'] is None, rows
    assert rows[0]['answered'] == rows[0]['goals'] > 0 and rows[0]['wrong_poses'] == 0 and rows[0]['hangs'] == 0
    assert rows[0]['recovery_s'] is not None, rows[0]
    assert '| laser_late | 1 |' in (tmp_path / 'REPORT.md').read_text()


def test_the_sensors_table_is_built_from_rows_per_setup_in_order_with_its_plot(tmp_path):
    from global_loc.bench.sensors import SETUPS, sensors_section
    from global_loc.bench.summary import summary_section

    def row(setup, ok, success, t, points=300, map_name='office'):
        return {'suite': 'sensors', 'map': map_name, 'sensors': setup, 'method': 'bnb', 'ok': ok, 'ok_loose': ok,
                'success': success, 'time_s': t, 'view_points': points, 'angle_step': 5}
    rows = [row('3D lidar', True, True, 0.02, 400), row('3D lidar', True, True, 0.04, 500),
            row('front 180°', False, True, 0.3), row('front 180°', False, False, 0.1),
            row('front + rear 2 × 270°', True, True, 0.01, map_name='willow')]
    lines = sensors_section(rows, str(tmp_path))
    table = [line for line in lines if line.startswith('| bnb |')]
    # setups in SETUPS' order, pooled over maps, then per map
    assert [line.split(' | ')[1] for line in table[:3]] == [SETUPS[0], SETUPS[2], SETUPS[3]]
    assert table[0] == '| bnb | front 180° | 2 | 300 | 0% | 50% | 50% | 0.200 | 0.290 |', table[0]
    assert table[2] == '| bnb | 3D lidar | 2 | 450 | 100% | 100% | 0% | 0.030 | 0.039 |', table[2]
    assert '| bnb | willow: front + rear 2 × 270° | 1 | 300 | 100% | 100% | 0% | 0.010 | 0.010 |' in table
    assert (tmp_path / 'sensors.png').stat().st_size > 5000
    assert any(line.startswith('| sensors |') and '| 5 | 60% | 20% |' in line for line in summary_section(rows))


@pytest.mark.process
def test_maps_suite_names_the_map_and_never_answers_identical_floors(tmp_path):
    every = [r for r in run_bench(tmp_path, '--suites', 'maps', '--poses', '10', '--jobs', '1')
             if r['suite'] == 'map_set']
    rows = [r for r in every if r['kind'] == 'map_set']
    assert {r['set'] for r in rows} == {'all', 'twins'} and len({r['map'] for r in rows}) >= 1
    assert not any(r['success'] for r in rows if r['set'] == 'twins')          # identical floors: never a guess
    assert all(r['answer_map'] in ('floor_1', 'floor_2') for r in rows if r['set'] == 'twins' and r['answer_map'])
    assert not any(r['success'] and not r['ok'] for r in rows)
    assert any(r['ok'] and r['success'] for r in rows if r['set'] == 'all')
    start_up = [r for r in every if r['kind'] == 'start_up']         # a stored pose: never confirmed wrong
    assert {r['case'] for r in start_up} >= {'kept', 'carried'}
    assert not any(r['confirmed'] and not r['ok'] for r in start_up)
    assert all(r['confirmed'] for r in start_up if r['case'] == 'kept')
    assert not any(r['confirmed'] for r in start_up if r['case'] == 'carried')
    assert {r['maps'] for r in every if r['kind'] == 'maps_n'} == set(range(1, 1 + rows[0]['maps']))
    report = (tmp_path / 'REPORT.md').read_text()          # the suite's own table leads its report
    assert report.index('## Which map am I on (maps suite)') < report.index('Command:')
    assert '### Time against the number of maps' in report and '| kept |' in report
    assert '| twins | every map |' in report


def test_the_tail_section_says_which_targets_are_met_from_its_rows():
    from global_loc.bench.tail import tail_section

    def row(kind, time_s, outcome='localized', ok=True, success=True, score=0.8, **extra):
        return {'suite': 'tail', 'kind': kind, 'time_s': time_s, 'outcome': outcome, 'ok': ok, 'success': success,
                'score': score, 'map': 'office', 'log': 'intel', 'expansions': 1000, **extra}
    changed = [row('changed', 0.1)] * 16 + [row('changed', 3.0, 'search_incomplete', True, False, 0.5,
                                                 expansions=400000)] * 3
    changed.append(row('changed', 5.0, 'search_incomplete', True, False, 0.6, expansions=90000))   # the time limit
    logs = [row('carmen', 0.05)] * 20
    big = [row('big', 0.4, cells=36_000_000, peak_mb=900, search_s=0.3, per_level=[0, 100, 200, 300, 400])] * 3
    text = '\n'.join(tail_section(changed + logs + big))
    lines = {line.split(' | ')[0]: line for line in text.splitlines() if line.startswith('| ')}
    assert '**not met**' in lines['| changed world, level 3: p95 ≤ 1 s']           # 3 s in its tail
    assert '3 of 3 stops' in next(v for k, v in lines.items() if 'node-budget stop' in k)   # score 0.5: explained
    assert lines['| changed world: 0 confident-wrong'].endswith('| 0 | met | |')
    assert '| met |' in next(v for k, v in lines.items() if k.startswith('| real logs'))
    assert '**not met**' in next(v for k, v in lines.items() if 'peak memory' in k)     # 900 MB > 800
    # 700 of 1000 expansions at the two top levels (blocks of 16 and 8 cells), 0.3 s / 1000
    big_line = next(v for k, v in lines.items() if '(36 Mcells)' in k)
    assert '70% of them at the two coarsest levels (blocks of 16 and 8 cells' in big_line
    assert '300.0 µs each' in big_line


@pytest.mark.process
def test_an_unknown_suite_exits_2_naming_the_suites_and_touches_nothing(tmp_path):
    (tmp_path / 'REPORT.md').write_text('an earlier report')
    done = subprocess.run([sys.executable, '-m', 'global_loc.bench', '--suite', 'nope', '--out', str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert 'unknown suite(s) nope' in done.stderr and 'unmapped' in done.stderr, done.stderr
    assert sorted(os.listdir(tmp_path)) == ['REPORT.md'] and (tmp_path / 'REPORT.md').read_text() == 'an earlier report'
