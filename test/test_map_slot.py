"""The newest map received is the one used, whatever order the precomputations finish in
(core.map_slot, without ROS): a map superseded while it was being prepared is dropped, and
a localization on an older generation is told its map is no longer current."""
import threading

from global_loc.core.map_slot import MapSlot


def slow_build_slot():
    """A MapSlot whose builder waits for `release[name]` before finishing map `name`."""
    release = {name: threading.Event() for name in ('big', 'small')}
    building = {name: threading.Event() for name in ('big', 'small')}
    changes = []

    def build(load):
        name = load()
        building[name].set()
        release[name].wait(10.0)
        return name
    slot = MapSlot(build, lambda installed, note, dropped: changes.append((installed.built, dropped)))
    return slot, release, building, changes


def test_a_map_superseded_while_building_is_dropped_and_the_newest_is_used():
    slot, release, building, changes = slow_build_slot()
    big = slot.submit(lambda: 'big')
    assert building['big'].wait(10.0)
    small = slot.submit(lambda: 'small')           # arrives while the big one builds
    assert not slot.is_current(big) and slot.is_current(small)
    release['big'].set()
    release['small'].set()
    installed = slot.wait_current(10.0)
    assert installed.built == 'small' and installed.generation == small
    assert changes == [(None, True), ('small', False)]  # the big one was never installed
    slot.close()


def test_a_request_waits_for_the_newest_map_and_a_failed_one_says_why():
    slot, release, building, _ = slow_build_slot()
    release['big'].set()
    slot.load_now(lambda: 'big')                   # a map file at configure: built in this thread
    first = slot.current()
    assert first.built == 'big' and slot.is_current(first.generation)
    slot.submit(lambda: 'small')
    assert building['small'].wait(10.0)
    assert slot.wait_current(0.1).built == 'big'   # still building: what is installed, not current
    assert not slot.is_current(first.generation)
    release['small'].set()
    assert slot.wait_current(10.0).built == 'small'

    def bad():
        raise ValueError('resolution 1e-08 m is outside [0.001, 10] m')
    slot.submit(bad)
    failed = slot.wait_current(10.0)
    assert failed.built is None and failed.error == 'map not loaded: resolution 1e-08 m is outside [0.001, 10] m'
    slot.close()
