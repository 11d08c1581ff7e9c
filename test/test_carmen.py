"""CARMEN logs -> records -> held-out fold maps (real data from ../shared/data/carmen)."""
import math

import numpy as np

from conftest import shared_path
from global_loc.bench.carmen import explained_fraction, held_out_folds
from global_loc.core.scan import scan_to_points
from global_loc.io.carmen import LogGrid, read_flaser


def test_intel_log_parses_with_beam_geometry_and_no_return_value():
    records = read_flaser(shared_path('carmen', 'intel-corrected.log.gz'))
    assert len(records) == 910
    scan = records[0].scan
    assert len(scan.ranges) == 180
    assert scan.angle_min == -math.pi / 2 and math.degrees(scan.angle_increment) == 1.0
    assert 80 < scan.range_max < 82                         # 0.99 x the log's ~81.8 no-return value
    assert records[0].pose.x == 0.600266 and records[0].timestamp > 0
    pts = scan_to_points(scan)
    assert pts.dropped['at_or_above_range_max'] > 0 or len(pts.points) == 180


def test_held_out_maps_never_contain_the_held_out_scans_and_filters_count():
    records = read_flaser(shared_path('carmen', 'intel-corrected.log.gz'))
    frame = LogGrid(records, 0.05)
    maps, kept, stats = held_out_folds(records, frame, folds=5)
    assert stats['scans'] == 910 and 0 < stats['explained_by_map'] <= stats['pose_on_free_space'] <= 910
    assert len(kept) == stats['explained_by_map']
    assert {h.fold for h in kept} == set(range(5))
    # Fold 0's map is built without fold 0: a map from fold 0 alone differs from it.
    only_first = frame.occupancy_map(frame.counts(records[:182]), 'fold 0 only')
    assert not np.array_equal(only_first.occupied, maps[0].occupied)
    # A kept scan is explained by its held-out map at its reference pose.
    assert explained_fraction(maps[kept[0].fold], kept[0].record) >= 0.7
    assert maps[0].occupied.sum() > 5000 and maps[0].free.sum() > 50000


def test_a_record_cut_short_or_without_beams_is_skipped_naming_its_line(tmp_path, caplog):
    """A log whose last line was cut mid-write, or with a record of 0 beams, is still a
    log: the bad record is skipped with a warning naming its line, the rest read."""
    import gzip
    import itertools
    with gzip.open(shared_path('carmen', 'intel-corrected.log.gz'), 'rt') as f:
        lines = list(itertools.islice(f, 3000))
    flaser = [i for i, line in enumerate(lines) if line.startswith('FLASER ')]
    assert len(flaser) >= 10
    lines[flaser[3]] = 'FLASER 0 0 0 0 0 0 0 1.0 host 1.0\n'                # no beams
    lines.append(lines[flaser[-1]][:len(lines[flaser[-1]]) // 2])           # cut mid-write
    log = tmp_path / 'cut.log'
    log.write_text(''.join(lines))
    with caplog.at_level('WARNING', logger='global_loc.io.carmen'):
        records = read_flaser(str(log))
    assert len(records) == len(flaser) - 1
    assert f'line {flaser[3] + 1}: FLASER record skipped: 0 beams' in caplog.text
    assert f'line {len(lines)}: FLASER record skipped' in caplog.text and 'cut short' in caplog.text
    assert flaser[3] + 1 not in [r.line for r in records]
