"""The benchmark harness end to end on a tiny run (real matchers, real report)."""
import json
import subprocess
import sys


def test_bench_writes_rows_report_and_plots(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'global_loc.bench', '--quick', '--suites', 'cut', '--poses', '5',
                          '--methods', 'template_ccoeff,features_orb', '--jobs', '2', '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [json.loads(line) for line in (tmp_path / 'rows.jsonl').read_text().splitlines()]
    # 1 pose x 3 radii x 2 maps; template at Δα 5 and 15, ORB once (Δα does not apply to it)
    assert {r['method'] for r in rows} == {'template_ccoeff', 'features_orb'}
    assert all({'ok', 'ok_loose', 'time_s', 'success'} <= set(r) for r in rows)
    assert any(r['ok'] for r in rows if r['method'] == 'template_ccoeff')
    report = (tmp_path / 'REPORT.md').read_text()
    assert 'Suite 1: local maps cut from the map' in report and '| cores |' in report
    assert 'time / baseline' in report and 'git_commit' in report
    assert (tmp_path / 'cut_time_vs_size.png').stat().st_size > 5000
