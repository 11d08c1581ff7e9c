"""Files that could hang a request, exhaust memory or flood a log - a map YAML or map-set
file of nested aliases (a "billion laughs" file), a file too big to be one, a stored pose
of nested brackets or at a FIFO, a map-set entry that is no map - each refused at once
with a short error naming the file and the problem (core/files.py)."""
import json
import os
import threading
import time

import pytest

from conftest import OFFICE_YAML
from global_loc.core.files import MAX_TEXT_BYTES
from global_loc.core.map_io import MapError, load_map_yaml
from global_loc.core.map_set import MapSetError, named_paths
from global_loc.core.stored_pose import StoredPoseError, load_stored_pose


def laughs(levels: int, key: str = 'image') -> str:
    """A YAML whose `key` expands to 10**levels strings through nested aliases."""
    lines = ['a0: &a0 "lol"']
    lines += [f'a{i}: &a{i} [{", ".join([f"*a{i - 1}"] * 10)}]' for i in range(1, levels + 1)]
    return '\n'.join(lines + [f'{key}: *a{levels}', 'resolution: 0.05', 'origin: [0, 0, 0]',
                              'occupied_thresh: 0.65', 'free_thresh: 0.2', ''])


def refused_fast(call, error, says: str, limit_s: float = 5.0) -> str:
    """`call` raises `error` matching `says` within `limit_s` (in a thread: a read that blocks
    fails the test instead of hanging it); the error's message."""
    outcome = {}

    def run():
        try:
            call()
        except Exception as e:      # noqa: BLE001 - the thread hands any error to the test
            outcome['error'] = e

    thread = threading.Thread(target=run, daemon=True)
    start = time.monotonic()
    thread.start()
    thread.join(limit_s)
    assert not thread.is_alive(), f'still reading after {limit_s} s'
    assert isinstance(outcome.get('error'), error), outcome
    message = str(outcome['error'])
    assert says in message, message
    assert time.monotonic() - start < limit_s
    return message


def test_a_map_yaml_of_nested_aliases_is_refused_at_once_with_a_short_error(tmp_path):
    path = tmp_path / 'laughs.yaml'
    path.write_text(laughs(6))       # a million strings expanded: nine levels would be gigabytes
    assert len(refused_fast(lambda: load_map_yaml(str(path)), MapError, 'aliases')) < 400


def test_a_map_set_file_of_nested_aliases_is_refused_as_a_map_would_be(tmp_path):
    path = tmp_path / 'building.yaml'
    path.write_text(laughs(6, key='maps'))

    def load():
        for one in named_paths([str(path)]).values():
            load_map_yaml(one)
    assert len(refused_fast(load, MapError, 'aliases')) < 400


def test_a_map_yaml_larger_than_any_map_yaml_is_refused_before_it_is_parsed(tmp_path):
    path = tmp_path / 'big.yaml'
    path.write_text(f'image: m.pgm\ncomment: "{"x" * MAX_TEXT_BYTES}"\n')
    refused_fast(lambda: load_map_yaml(str(path)), MapError, f'larger than {MAX_TEXT_BYTES} bytes')


def test_a_long_value_is_echoed_cut_to_a_line(tmp_path):
    path = tmp_path / 'long.yaml'
    path.write_text(f'image: m.pgm\nresolution: 0.05\norigin: [{", ".join(["1"] * 5000)}]\n'
                    f'occupied_thresh: 0.65\nfree_thresh: 0.2\n')
    message = refused_fast(lambda: load_map_yaml(str(path)), MapError, 'origin must be [x, y, yaw]')
    assert len(message) < 300, message


def test_a_map_set_entry_that_is_no_map_says_what_is_wrong_with_it(tmp_path):
    listing = tmp_path / 'building.yaml'
    for text, says in (('maps:\n  - lift=B: office.yaml\n', 'the map name \'lift=B\' cannot'),
                       ('maps:\n  - building.yaml\n', 'is this file itself'),
                       ('maps:\n  - floor_1: ./building.yaml\n', 'is this file itself')):
        listing.write_text(text)
        with pytest.raises(MapSetError) as refused:
            named_paths([str(listing)])
        assert says in str(refused.value), str(refused.value)
    (tmp_path / 'wing.yaml').write_text(f'maps:\n  - {OFFICE_YAML}\n')
    listing.write_text('maps:\n  - wing.yaml\n')
    with pytest.raises(MapSetError, match='is another map-set file'):
        named_paths([str(listing)])


def test_a_stored_pose_of_nested_brackets_is_unreadable_not_a_crash(tmp_path):
    path = tmp_path / 'pose.json'
    path.write_text('[' * 100_000 + ']' * 100_000)
    refused_fast(lambda: load_stored_pose(str(path)), StoredPoseError, 'cannot be read')


def test_a_stored_pose_at_a_fifo_is_refused_without_blocking(tmp_path):
    path = tmp_path / 'pose.json'
    os.mkfifo(path)
    try:
        refused_fast(lambda: load_stored_pose(str(path)), StoredPoseError, 'a FIFO (named pipe), not a file')
    finally:
        try:     # a reader the old code left blocked on the FIFO is let go
            os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass


def test_a_stored_pose_file_too_big_to_be_one_is_refused(tmp_path):
    path = tmp_path / 'pose.json'
    path.write_text(json.dumps({'pad': 'x' * MAX_TEXT_BYTES}))
    refused_fast(lambda: load_stored_pose(str(path)), StoredPoseError, 'larger than')
