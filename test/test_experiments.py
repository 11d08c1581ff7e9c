"""The experiments under benchmarks/experiments/ import, run and read their rows: they are
how the decision records got their numbers, so they must not rot."""
import json

import pytest

from benchmarks.experiments import band_replay, follow_ab, options_ab


def test_an_ab_run_records_the_peaks_through_the_hook_and_identical_arms_agree(tmp_path, capsys):
    """Arm B with bnb's own options is arm A: no outcome may differ, and each row carries the
    peaks on_peaks handed over (the scan's own search first)."""
    out = tmp_path / 'ab'
    assert options_ab.main(['--suites', 'cut', '--poses', '5', '--shared', str(tmp_path / 'none'),
                            '--a', 'band_allowance=1.0', '--b', 'band_allowance=1.0', '--out', str(out)]) == 0
    rows = [json.loads(line) for line in (out / 'rows.jsonl').read_text().splitlines()]
    assert {r['arm'] for r in rows} == {'A', 'B'} and len(rows) == 2 * len({r['trial'] for r in rows})
    assert all(r['peak_leaf'] and len(r['peak_fit']) == len(r['peak_leaf']) and r['candidates'] for r in rows)
    assert all(r['searches'] >= 1 and r['options'] == {'band_allowance': 1.0} for r in rows)
    table = options_ab.summarize([str(out / 'rows.jsonl')])
    assert table[2].startswith('| cut |') and table[2].endswith('| 0 |'), table      # no outcome changed
    assert band_replay.main([str(out / 'rows.jsonl')]) == 0
    assert 'replayed at band_allowance 0.03' in capsys.readouterr().out


def test_an_unknown_option_is_refused_with_the_known_names():
    with pytest.raises(SystemExit, match='band_alowance: not a BranchAndBoundOptions field.*band_allowance'):
        options_ab.parse_options(['band_alowance=0.03'])


def test_the_follow_ab_reads_its_rows(tmp_path):
    rows = tmp_path / 'rows.jsonl'
    base = {'log': 'intel', 'index': 3, 'followed': True, 'settled': True}
    rows.write_text('\n'.join(json.dumps({**base, 'arm': arm, 'outcome': 'localized', 'ok': ok})
                              for arm, ok in (('A', True), ('B', False))) + '\n')
    lines = follow_ab.summarize([str(rows)])
    assert '| intel | B | 1 | 0 | 1 | 1 | 1 |' in lines
    assert lines[-1] == '- intel start 3: localized ok=True -> localized ok=False'
