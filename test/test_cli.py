"""The CLI end to end in real subprocesses: simulate scans, localize them, a bad line."""
import json
import os
import subprocess
import sys

import pytest

from conftest import OFFICE_YAML
from global_loc.core.transform import Rigid2D, pose_correct


def run_cli(*args, stdin=None):
    return subprocess.run([sys.executable, '-m', 'global_loc', *args], input=stdin, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.process
def test_cli_localizes_simulated_scans_and_reports_a_bad_line(tmp_path):
    sim = run_cli('simulate', '--map', OFFICE_YAML, '--count', '3', '--seed', '3')
    assert sim.returncode == 0, sim.stderr
    lines = sim.stdout.splitlines()
    assert len(lines) == 3 and 'truth' in json.loads(lines[0])
    bad = json.loads(lines[0])
    bad['ranges'] = [None] * len(bad['ranges'])
    scans = tmp_path / 'scans.jsonl'
    scans.write_text('\n'.join([lines[0], 'not json', json.dumps(bad), lines[1], lines[2]]) + '\n')
    plot = tmp_path / 'out.png'
    out = run_cli('localize', '--map', OFFICE_YAML, '--scans', str(scans), '--method', 'template_ccoeff',
                  '--plot', str(plot))
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(rows) == 5
    assert 'error' in rows[1] and 'line 2' in rows[1]['error']
    assert 'no valid reading' in rows[2]['error']
    assert rows[1]['outcome'] == rows[2]['outcome'] == 'unusable_scan'
    good = [rows[0], rows[3], rows[4]]
    for row in good:
        assert {'x', 'y', 'yaw', 'score', 'success', 'outcome', 'time_s', 'method', 'hypotheses'} <= set(row)
        assert row['method'] == 'template_ccoeff'
        assert row['success'] == (row['outcome'] == 'localized')
    assert sum(pose_correct(Rigid2D(r['x'], r['y'], r['yaw']), Rigid2D(**r['truth'])) for r in good) >= 2
    assert os.path.getsize(plot) > 10000


@pytest.mark.process
def test_cli_unknown_method_and_missing_map_exit_with_a_message(tmp_path):
    scans = tmp_path / 's.jsonl'
    scans.write_text('')
    out = run_cli('localize', '--scans', str(scans), '--method', 'magic')
    assert out.returncode == 2 and 'unknown method' in out.stderr
    out = run_cli('localize', '--scans', str(scans), '--map', str(tmp_path / 'no.yaml'))
    assert out.returncode == 2 and 'not found' in out.stderr


@pytest.mark.process
def test_cli_bnb_options_are_flags(tmp_path):
    """--bnb-max-nodes reaches the matcher: a budget of 50 expansions ends every search incomplete."""
    sim = run_cli('simulate', '--map', OFFICE_YAML, '--count', '2', '--seed', '1')
    scans = tmp_path / 'scans.jsonl'
    scans.write_text(sim.stdout)
    rows = [json.loads(line) for line in run_cli('localize', '--scans', str(scans)).stdout.splitlines()]
    assert [r['outcome'] for r in rows] == ['localized', 'localized']
    # bnb's search statistics ride along; its search is part of the localization's time
    assert all(r['search']['exact'] and r['search']['expansions'] > 50 and r['search']['headings'] > 0
               and 0 < r['search']['search_s'] < r['time_s'] for r in rows)
    out = run_cli('localize', '--scans', str(scans), '--bnb-max-nodes', '50')
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r['outcome'] for r in rows] == ['search_incomplete', 'search_incomplete']
    assert all('stopped after 50 node expansions' in r['message'] and not r['success'] for r in rows)
    assert all(not r['search']['exact'] and r['search']['expansions'] >= 50 for r in rows)
    assert '--bnb-keep-ratio' in run_cli('localize', '--help').stdout


@pytest.mark.process
def test_cli_localizes_in_a_map_set_and_every_line_names_its_map(tmp_path):
    """Two --map: each line names the map of its answer; the same map twice (identical floors)
    is ambiguous with a hypothesis on each; a name given twice is refused."""
    scans = tmp_path / 'scans.jsonl'
    scans.write_text(run_cli('simulate', '--map', OFFICE_YAML, '--count', '3', '--seed', '4').stdout)
    one = [json.loads(line) for line in run_cli('localize', '--scans', str(scans)).stdout.splitlines()]
    assert [r['map'] for r in one] == ['office'] * 3
    out = run_cli('localize', '--scans', str(scans), '--map', OFFICE_YAML, '--map', f'floor_2={OFFICE_YAML}')
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert len(rows) == 3 and all(r['outcome'] == 'ambiguous' and not r['success'] for r in rows), out.stderr
    assert all({h['map'] for h in r['hypotheses'][:2]} == {'office', 'floor_2'} for r in rows)
    assert all(r['map'] in ('office', 'floor_2') for r in rows)
    twice = run_cli('localize', '--scans', str(scans), '--map', OFFICE_YAML, '--map', OFFICE_YAML)
    assert twice.returncode == 2 and 'two maps named office' in twice.stderr
