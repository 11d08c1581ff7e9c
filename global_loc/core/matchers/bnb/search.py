"""The best-first branch-and-bound search on every core (after Cartographer's
FastCorrelativeScanMatcher2D): runs kernels.search_step in slices, so that progress is
reported and a cancel is seen between them, on one heap per thread.

The top nodes are dealt to one heap per thread (the kernel releases the GIL); the
threads share the best leaf found so far, so each prunes by the best any has found. A
thread whose heap runs out takes half of the fullest one. The result does not depend on
the threads: every node reaching the final best's band (verdict.keep_floor) is expanded
whatever the order, and the leaves are put in pose order before anyone picks peaks from them.
"""
from __future__ import annotations

import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, NamedTuple, Optional

import cv2
import numpy as np

from ..base import ProgressFn
from .heap import PAD, make_heap, split_heap
from .kernels import FreeBlocks, Planes, ScanTables, SearchSpace, dive, node_bounds, search_step
from .verdict import keep_floor


@dataclass(frozen=True)
class SearchStats:
    """What one search did (diagnostics; the verdict reads the band it searched)."""
    exact: bool            # False when max_nodes, the time limit or the settled end stopped it
    angles: int            # leaf headings over 360 deg
    points: int            # scan points searched with
    leaves: int            # leaves within the searched band of the best (verdict.searched_keep)
    expansions: int
    per_level: tuple       # expansions per level
    top_nodes: int
    threads: int
    best_leaf: float       # the best leaf's score, in [0, 1]
    search_s: float = 0.0  # seconds in the search proper (the tree), not in preparing the scan's
                           # tables or refining, checking and ranking the peaks
    settled: bool = False  # it ended early: its answer could not become confident (matcher.settled_check)
    band_allowance: float = 1.0   # the band it searched (the option's, or 1 once resumed with the whole band)
    top_in_band: int = 0   # top nodes bounded within the final best's band: each must be expanded for an
                           # exhaustive search (the least it needs, whatever the levels below prune)


# settled(leaves kept so far, highest pending bound (raw)) -> whether the search may end there
SettledFn = Callable[[np.ndarray, int], bool]


class SearchInput(NamedTuple):
    """What the compiled kernels read (arrays and named tuples, not objects): the map's
    planes and free blocks, and the scan's tables."""
    planes: Planes
    tables: ScanTables
    free: FreeBlocks


class Paused(NamedTuple):
    """A search stopped at its node budget, to go on with a larger one instead of starting
    again (a map set's probe rounds, then its search): one heap per thread, the leaves
    found, the expansions per thread and level and in all, the best leaf (raw) and whether
    it had gone on with Resume's band."""
    heaps: list
    found: list
    per_level: list
    expanded: int
    best: int
    resumed: bool


class SearchStart(NamedTuple):
    """Where a search starts: its space (the map, the band's options, the prior), the top
    nodes (rows u, v, a, raw bound) at top_level, and a raw score some place is known to
    reach (MatchOptions.incumbent), pruned by from the start; or where a search of the
    same scan and space paused (its top nodes then already expanded). A higher incumbent
    than the paused search's only prunes more: every node it left reaches the final band
    or is pruned when taken, as in a search that started with it."""
    space: SearchSpace
    top_nodes: np.ndarray
    top_level: int
    incumbent: int = 0
    paused: Optional[Paused] = None


class RunLimits(NamedTuple):
    """When a search stops short: after max_nodes expansions or at the deadline
    (time.monotonic()); `progress` is told between slices (a cancel raises there)."""
    max_nodes: int
    deadline: float = math.inf
    progress: Optional[ProgressFn] = None


class Resume(NamedTuple):
    """A lower floor the search can resume with once its own band is searched: the nodes
    and leaves above `space`'s floor are held meanwhile, so the resumed search expands
    exactly what a search with `space` from the start would."""
    space: SearchSpace                       # the same space, a wider band
    needed: Callable[[np.ndarray], bool]     # the narrow band's leaves -> whether to resume


class SearchRun(NamedTuple):
    """What ThreadedSearch.run returns."""
    leaves: np.ndarray       # rows u, v, angle index, raw optimistic score, raw evidence: the leaves whose
                             # optimistic score reaches the band of the best evidence, in pose order
    per_level: np.ndarray    # expansions per level
    exact: bool              # the whole band was searched
    settled: bool            # `settled` ended it: the band not all searched, the answer not to become confident
    resumed: bool = False    # it went on with Resume's band: the leaves are that band's
    paused: Optional[Paused] = None     # where it stopped, when the node budget stopped it


def search_threads() -> int:
    """Search threads: as many as OpenCV may use (cv2.getNumThreads(), by default one per
    core), so one setting - cv2.setNumThreads - governs every matcher; the benchmark
    gives each worker process its share of the cores that way."""
    return max(1, cv2.getNumThreads())


class ThreadedSearch:
    """Owns the search's worker threads (kept between searches: starting threads per
    search costs time and, with glibc's per-thread arenas, memory); keeps no state of a
    search, so concurrent searches on one matcher are independent."""

    def __init__(self, slice_expansions: int = 5000):
        self.slice_expansions = slice_expansions
        self._lock = threading.Lock()
        self._pool: Optional[ThreadPoolExecutor] = None
        self._pool_threads = 0

    def _executor(self, threads: int) -> ThreadPoolExecutor:
        with self._lock:
            if self._pool is None or self._pool_threads != threads:
                self._pool, self._pool_threads = ThreadPoolExecutor(threads, thread_name_prefix='bnb'), threads
            return self._pool

    def node_bounds(self, planes: Planes, tables: ScanTables, tu, tv, ta, level: int) -> np.ndarray:
        """kernels.node_bounds on every search thread, the nodes in one chunk a thread (the
        top nodes of a 36 Mcell map take ~0.1 s on one core); the same integers."""
        threads = search_threads()
        if threads == 1 or len(tu) < 4096:       # few nodes (small maps): this thread
            return node_bounds(planes, tables, tu, tv, ta, level)
        chunks = zip(*(np.array_split(x, threads) for x in (tu, tv, ta)), strict=True)     # views, in order
        return np.concatenate(list(self._executor(threads).map(
            lambda chunk: node_bounds(planes, tables, *chunk, level), chunks)))

    def run(self, given: SearchInput, begin: SearchStart, limits: RunLimits, settled: Optional[SettledFn] = None,
            resume: Optional[Resume] = None) -> SearchRun:
        """Expand every node whose bound reaches the best leaf's band (keep_floor), from the top
        nodes. Returns the leaves scoring that high (rows u, v, angle index, raw score) in
        pose order, the expansions per level, whether the search was exhaustive (not stopped
        by the limits), whether `settled` ended it and whether it resumed. It holds a leaf
        from the start (a greedy dive from each thread's best top node), so a search stopped
        at once still returns its best leaf found.

        settled(leaves, top): called between slices with the leaves kept so far and the
        highest bound still pending (raw; no leaf not scored yet scores more); True ends the
        search there - for an answer the rest cannot change. resume: once the start's band
        is searched, resume.needed(its leaves) says whether to go on with resume.space's
        (lower) floor. The band below a leaf at poor_fit is always held: expanded once a leaf
        reaches poor_fit where `space` has poor_band 0 (kernels.SearchSpace)."""
        planes, tables, free = given
        space, top_level = begin.space, begin.top_level
        max_nodes, deadline, progress = limits
        threads = search_threads()
        held = (resume.space if resume is not None else space)._replace(poor_band=1.0)
        heaps, found, per_level, expanded, best, resumed = start_or_go_on(given, begin, threads)
        shared_best = np.zeros(PAD, np.int64)
        shared_best[0] = max(best, begin.incumbent)
        done = [False] * threads
        band = [held if resumed else space]   # the band being expanded: `space`'s, then held's once resumed
        n_points = tables.du.shape[1]

        def run(k, budget):
            n, done[k], leaves, heaps[k] = search_step(planes, tables, free, band[0], held, heaps[k], shared_best,
                                                       budget, per_level[k])
            return n, leaves

        def result(exact: bool, ended: bool = False) -> SearchRun:
            stopped = None if exact or ended or expanded < max_nodes else \
                Paused(heaps, found, per_level, expanded, int(shared_best[0]), band[0] is not space)
            return SearchRun(kept_leaves(found, band[0], shared_best[0], n_points),
                             np.sum(per_level, axis=0)[:top_level + 1], exact, ended, band[0] is not space, stopped)

        while time.monotonic() <= deadline:
            budget = max(1, min(self.slice_expansions, max_nodes - expanded) // threads)
            if threads == 1:
                results = [run(0, budget)]
            else:
                results = list(self._executor(threads).map(run, range(threads), [budget] * threads))
            expanded += sum(n for n, _ in results)
            found.extend(leaves for _, leaves in results)
            if all(done) and resume is not None and band[0] is not held and \
                    resume.needed(kept_leaves(found, space, shared_best[0], n_points)):
                band[0], done = held, [False] * threads
            elif all(done) or expanded >= max_nodes:     # (the deadline: the loop's condition)
                break
            if settled is not None:
                top = max((int(h[0][0]) >> 3 for h in heaps if h[2][0] > 0), default=-1)   # (heap_key)
                if settled(kept_leaves(found, band[0], shared_best[0], n_points), top):
                    return result(False, True)
                found = [kept_leaves(found, held, shared_best[0], n_points)]   # all a later slice needs (floors rise)
            share_work(heaps, done)
            if progress:   # the server's progress callback raises CanceledError on a cancel request
                progress(min(0.95, expanded / max_nodes), shared_best[0] / (255.0 * n_points))
        return result(all(done))


def start_or_go_on(given: SearchInput, begin: SearchStart, threads: int) -> Paused:
    """A search's state at its start: begin.paused's (a copy of its leaves list), or the
    heaps and the dive's leaves of a new one, nothing expanded yet."""
    paused = begin.paused
    if paused is not None and len(paused.heaps) == threads:
        return paused._replace(found=list(paused.found))
    heaps, found = start(given, begin, threads)
    per_level = [np.zeros(max(begin.top_level + 1, PAD), np.int64) for _ in heaps]   # PAD: see kernels
    return Paused(heaps, found, per_level, 0, int(found[0][:, 4].max(initial=0)), False)


def start(given: SearchInput, begin: SearchStart, threads: int) -> tuple[list, list[np.ndarray]]:
    """One heap per thread, the best top nodes dealt evenly, and the leaves of a greedy dive
    from each thread's best (the first incumbent: a real leaf, so the result is the same)."""
    planes, tables, free = given
    space, top_nodes, top_level = begin.space, begin.top_nodes, begin.top_level
    order = np.argsort(-top_nodes[:, 3], kind='stable')
    heaps = [make_heap(top_nodes[order[k::threads]], top_level) for k in range(threads)]
    dived = np.stack([dive(planes, tables, free, space, *top_nodes[i, :3], top_level) for i in order[:threads]])
    # (rows u, v, a, optimistic, evidence; -1 where no child qualified)
    return heaps, [dived[dived[:, 3] >= 0]]


def share_work(heaps: list, done: list[bool]) -> None:
    """An idle thread (done) takes half of the fullest heap."""
    for k in range(len(heaps)):
        if done[k]:
            j = max(range(len(heaps)), key=lambda i: heaps[i][2][0])
            if heaps[j][2][0] > 1:
                heaps[k], heaps[j] = split_heap(*heaps[j])
                done[k] = done[j] = False


def kept_leaves(found: list[np.ndarray], space: SearchSpace, best: int, n_points: int) -> np.ndarray:
    """The leaves found (lists of rows u, v, a, raw optimistic score, raw evidence) whose
    optimistic score reaches the band of the best evidence (keep_floor; a poor best,
    under its floor, is kept with what reaches it), once each, in pose order - not the
    order the threads found them: equal scores then pick the same peaks whatever the
    threads (the search may find a dive's leaf again)."""
    leaves = np.concatenate(found) if found else np.empty((0, 5), np.int64)
    leaves = leaves[leaves[:, 3] >= min(keep_floor(space, best, n_points), best)]
    _, first = np.unique((leaves[:, 0] * space.map_h + leaves[:, 1]) * space.n_angles + leaves[:, 2],
                         return_index=True)
    return leaves[first]


def top_in_band(bounds: np.ndarray, space: SearchSpace, leaves: np.ndarray, n_points: int) -> int:
    """How many top nodes (their raw bounds) reach the band of the best evidence of `leaves`
    (search_step's rows) on n_points points: nodes an exhaustive search has to expand, so a
    lower limit on the expansions it needs (on a large building most top bounds are near a
    full fit)."""
    best = int(leaves[:, 4].max(initial=0))
    return int(np.count_nonzero(bounds >= keep_floor(space, best, n_points)))
