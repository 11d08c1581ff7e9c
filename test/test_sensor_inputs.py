"""The server's wait for a view of several sensors, without a node: the first message after
the request opens a window of merge_window_s; a sensor that stays silent does not hold the
request, however often another one publishes."""
import threading
import time

import pytest

from global_loc.ros.sensors import SCAN, SensorInputs, SensorSpec

pytestmark = pytest.mark.ros     # ros/sensors.py imports ROS message types


def test_a_silent_sensor_does_not_hold_the_view_while_another_keeps_publishing():
    inputs = SensorInputs()
    inputs.configure((SensorSpec('/scan', SCAN, primary=True), SensorSpec('/scan_rear', SCAN)))
    stop = threading.Event()

    def front():            # 50 Hz: its newest message is always younger than the window
        while not stop.is_set():
            inputs.put('/scan', object())
            time.sleep(0.02)
    threading.Thread(target=front, daemon=True).start()
    try:
        t0 = time.monotonic()
        newest = inputs.wait(t0, timeout=10.0, window=0.2)
        waited = time.monotonic() - t0
    finally:
        stop.set()
    assert set(newest) == {'/scan'} and waited < 2.0, waited


def test_nothing_after_the_request_is_none_at_the_timeout():
    inputs = SensorInputs()
    inputs.configure((SensorSpec('/scan', SCAN, primary=True),))
    inputs.put('/scan', object())                     # before the request: stale
    assert inputs.wait(time.monotonic() + 0.01, timeout=0.2, window=0.1) is None
