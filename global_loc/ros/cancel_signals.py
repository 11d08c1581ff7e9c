"""Signals that cancel a running goal instead of ending the process (ros/api.py's
localize): rclpy's own SIGINT/SIGTERM handlers shut every context down at the signal, so
the cancel could not be sent; they are set aside for the signals taken and put back after."""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Callable

from rclpy import signals as rclpy_signals


@contextlib.contextmanager
def signals_routed_to(handler: Callable, signals: tuple):
    """While inside, `signals` call `handler(signum, frame)`; rclpy keeps the others it
    handled. Only the main thread owns signals: elsewhere nothing changes. A signal the
    process ignores (a background job's SIGINT) stays ignored."""
    if threading.current_thread() is not threading.main_thread() or not signals:
        yield
        return
    rclpy_options = rclpy_signals.get_current_signal_handlers_options()
    rclpy_had = _SIGNALS_OF[rclpy_options]
    if rclpy_had:
        rclpy_signals.uninstall_signal_handlers()
    taken = [s for s in signals if signal.getsignal(s) != signal.SIG_IGN]
    previous = {s: signal.signal(s, handler) for s in taken}
    rclpy_keeps = rclpy_had - set(taken)
    if rclpy_keeps:
        rclpy_signals.install_signal_handlers(_OPTIONS_OF[frozenset(rclpy_keeps)])
    try:
        yield
    finally:
        if rclpy_keeps:
            rclpy_signals.uninstall_signal_handlers()
        for s, old in previous.items():
            signal.signal(s, old)
        if rclpy_had:
            rclpy_signals.install_signal_handlers(rclpy_options)


_Options = rclpy_signals.SignalHandlerOptions
_SIGNALS_OF = {_Options.NO: frozenset(), _Options.SIGINT: frozenset({signal.SIGINT}),
               _Options.SIGTERM: frozenset({signal.SIGTERM}), _Options.ALL: frozenset({signal.SIGINT, signal.SIGTERM})}
_OPTIONS_OF = {signals: options for options, signals in _SIGNALS_OF.items()}
