"""glibc heap settings that keep a long-running node's memory bounded.

A search allocates large temporary arrays (grids, heaps, score images) on whichever
thread runs it. glibc gives each thread that contends for the heap its own arena (up to
8 per core) and rarely returns their free pages, so a server's RSS kept rising with
searches that ran on different executor and search threads (measured: 247 ->
1307 MB over 23 budget-exhausting goals). Two arenas, and giving free pages back after
each request, keep it flat (measured by the soak benchmark, `--suites soak`).
"""
from __future__ import annotations

import ctypes
import ctypes.util

M_ARENA_MAX = -8       # mallopt parameter (malloc.h)


def _libc():
    name = ctypes.util.find_library('c')
    try:
        libc = ctypes.CDLL(name)
        return libc if hasattr(libc, 'mallopt') and hasattr(libc, 'malloc_trim') else None
    except OSError:
        return None      # not glibc (musl, macOS): nothing to tune


_LIBC = _libc()


def limit_arenas(arenas: int = 2) -> bool:
    """Cap glibc's heap arenas; call before threads start. False where not glibc."""
    return bool(_LIBC and _LIBC.mallopt(M_ARENA_MAX, arenas))


def release_free_memory() -> None:
    """Return free heap pages to the system (after a request's temporaries are freed)."""
    if _LIBC:
        _LIBC.malloc_trim(0)
