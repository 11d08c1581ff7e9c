"""The map a server localizes in, when maps keep arriving (a SLAM node republishing,
map_server's load_map called twice): the newest map received is the one used, whatever
order their precomputations finish in.

Every map gets a generation number when it is *received*. One worker thread builds
(precomputes) the newest pending map; a map that a newer one superseded while it was
waiting or building is dropped, never installed. A localization remembers the
generation it ran on; `is_current(generation)` is false as soon as a newer map has been
received - even before that one is ready - so a pose computed in a replaced map is not
published. One builder, not one per map: two big precomputations at once would also
double the memory. No ROS here, so the rule is tested without processes.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable, Generic, Optional, TypeVar

L = TypeVar('L')     # what a map is built into (the server: a Localizer)


@dataclass(frozen=True)
class Installed(Generic[L]):
    generation: int
    built: Optional[L]         # None: no usable map (see error)
    error: str = ''


class MapSlot(Generic[L]):
    def __init__(self, build: Callable[[Callable], L], on_change: Callable[[Installed, str], None] = lambda *a: None,
                 no_map: str = 'no map loaded yet'):
        """`build(load)` turns `load()` (which returns the map, or raises) into what is used;
        exceptions it raises are the map's error (ValueError: its message; others with their
        type). `on_change(installed, note, dropped)` is told each install, failure or drop (a log line)."""
        self._build = build
        self._on_change = on_change
        self._cond = threading.Condition()
        self._received = 0                      # generation of the newest map received
        self._pending: Optional[tuple[int, Callable]] = None
        self._installed: Installed = Installed(0, None, no_map)
        self._closed = False
        self._worker: Optional[threading.Thread] = None

    def current(self) -> Installed:
        with self._cond:
            return self._installed

    def is_current(self, generation: int) -> bool:
        """Whether no map newer than `generation` has been received."""
        with self._cond:
            return generation == self._received

    def clear(self, reason: str) -> None:
        """Drop the map (cleanup): requests get `reason` until a new map is installed."""
        with self._cond:
            self._received += 1
            self._pending = None
            self._installed = Installed(self._received, None, reason)

    def load_now(self, load: Callable) -> Installed:
        """Build `load()`'s map in this thread and install it (a map file at configure)."""
        with self._cond:
            self._received += 1
            generation, self._pending = self._received, None
        return self._finish(generation, load)

    def submit(self, load: Callable) -> int:
        """Queue a received map for the worker; returns its generation."""
        with self._cond:
            if self._closed:
                return self._received
            self._received += 1
            self._pending = (self._received, load)
            if self._worker is None:
                self._worker = threading.Thread(target=self._run, name='map_builder', daemon=True)
                self._worker.start()
            self._cond.notify_all()
            return self._received

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._pending = None
            self._cond.notify_all()

    def wait_current(self, timeout: float, cancelled: Callable[[], bool] = lambda: False,
                     poll_s: float = 0.05) -> Installed:
        """The installed map once it is the newest received (a newer one may be building),
        or whatever is installed when `timeout` passes or `cancelled()` says so."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._installed.generation != self._received and not cancelled():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._cond.wait(min(poll_s, remaining))
            return self._installed

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._closed)
                if self._closed:
                    return
                (generation, load), self._pending = self._pending, None
            self._finish(generation, load)     # notifies the waiters itself

    def _finish(self, generation: int, load: Callable) -> Installed:
        try:
            built, error = self._build(load), ''
        except ValueError as e:
            built, error = None, f'map not loaded: {e}'
        except Exception as e:      # an internal error must not end the worker: say what it was
            built, error = None, f'map not loaded: {type(e).__name__}: {e}'
        with self._cond:
            dropped = generation != self._received
            if dropped:
                note = f'map {generation} dropped: map {self._received} arrived while it was being prepared'
                installed = self._installed
            else:
                installed = self._installed = Installed(generation, built, error)
                note = error or f'map {generation} in use'
            self._cond.notify_all()
        self._on_change(installed, note, dropped)
        return installed
