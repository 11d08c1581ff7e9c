"""One verdict for every method: a thesis matcher's answer is checked on the map with
bnb's verdict (core/matchers/verify.py) before it can be a success. Simulated office scans
where rotated template matching is confidently wrong by its own verdict (the best leads the
next by 1%) are not confident once checked; one it gets right stays right and confident."""
import json

import pytest

from conftest import OFFICE_YAML, seeded_office_scans
from global_loc.core.localizer import Localizer, LocalizerConfig
from global_loc.core.outcome import Outcome
from global_loc.core.transform import pose_correct


@pytest.fixture(scope='module')
def office_scans():
    return seeded_office_scans(11)


@pytest.mark.parametrize('index', [1, 10])
def test_a_confidently_wrong_template_answer_is_not_confident_once_checked(office_scans, index):
    office, scans = office_scans
    scan, truth = scans[index]
    raw = Localizer(office, LocalizerConfig(verify=False)).localize(scan, 'template_ccoeff')
    assert raw.success and not pose_correct(raw.pose, truth) and raw.raw is None     # the thesis's own verdict
    checked = Localizer(office).localize(scan, 'template_ccoeff')
    assert not checked.success and checked.outcome == Outcome.AMBIGUOUS, checked.message
    assert 'map check' in checked.message
    assert checked.raw.success and not pose_correct(checked.raw.pose, truth)          # kept, for the benchmark
    assert pose_correct(checked.pose, truth)         # the check's best place is the true one, not vouched for


def test_a_right_template_answer_stays_right_and_confident_once_checked(office_scans):
    office, scans = office_scans
    scan, truth = scans[0]
    checked = Localizer(office).localize(scan, 'template_ccoeff')
    assert checked.success and pose_correct(checked.pose, truth) and checked.raw.success, checked.message
    assert pose_correct(checked.raw.pose, truth)
    assert checked.method == 'template_ccoeff'


def test_the_cli_prints_the_raw_verdict_and_no_verify_gives_the_thesis_answer(office_scans, tmp_path, capsys):
    from global_loc.offline.cli import main
    _, scans = office_scans
    path = tmp_path / 'scans.jsonl'
    path.write_text(json.dumps({**scans[1][0].to_dict(), 'truth': scans[1][1].as_dict()}) + '\n')
    assert main(['localize', '--map', OFFICE_YAML, '--scans', str(path), '--method', 'template_ccoeff']) == 0
    checked = json.loads(capsys.readouterr().out)
    assert checked['raw']['success'] and not checked['success'], checked
    assert main(['localize', '--map', OFFICE_YAML, '--scans', str(path), '--method', 'template_ccoeff',
                 '--no-verify']) == 0
    raw = json.loads(capsys.readouterr().out)
    assert raw['success'] and raw['error_xy'] > 0.2 and 'raw' not in raw, raw


def test_only_a_matcher_that_scores_a_pose_is_a_tracker_and_the_localizer_says_which_tracks(office_map):
    from global_loc.core.matchers import TRACKER_METHOD, Tracker
    localizer = Localizer(office_map, LocalizerConfig(method='template_ccoeff'))
    assert isinstance(localizer.matcher('bnb'), Tracker)
    for method in ('template_ccoeff', 'template_sqdiff', 'features_orb'):
        assert not isinstance(localizer.matcher(method), Tracker)
        assert localizer.tracker(method).name == TRACKER_METHOD
    assert localizer.tracker() is localizer.matcher(TRACKER_METHOD)
    assert localizer.tracker('bnb') is localizer.matcher('bnb')
