"""Compiled (numba) inner loops of the branch-and-bound search: a node's bound and the
best-first search itself (its pending nodes: heap.py). numpy cannot walk a search tree
one node at a time fast enough. Numbers only here: the geometry (angle tables, which
plane each point reads) is prepared by matcher.py, the planes by grids.py. Compiled on
first use and cached on disk (numba cache=True).

A node is (u, v, a, h): cells u .. u + 2^h - 1, v .. v + 2^h - 1 of the map, angle
indices a .. a + 2^h - 1. Its bound is the sum over the scan's points of the point's
plane (the one widened for its range) at the point's cell, the point rotated by the
node's middle angle (row row_start[h] + a >> h of the offset tables), an integer.

Two scores per pose: the evidence (what the map explains: unknown cells count for
nothing), by which the best leaf, and so the band, is chosen; and the optimistic score,
which the bounds bound and the band is cut by, so that a place is never pruned for what
the map does not say: unknown cells a beam can reach may hide a wall (the optimistic
planes), but at most bnb.unknown_credit of the scan is credited that way - the
score is min(optimistic sum, evidence sum + that share), both sums bounded by their own
planes (a map without unknown cells has one set, and the two scores are one).

The kernels take named tuples (numba compiles attribute reads to plain loads): `Planes`
(per map: where a plane's cell is in the one flat array), `ScanTables` (per scan: each
point's offsets and planes), `FreeBlocks` (per map) and `SearchSpace`.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit, uint64

from ...pixel_kernels import image_point
from .heap import heap_key, heap_pop, heap_push, make_heap, split_heap
from .verdict import keep_floor

# Plane k starts at flat[offsets[k]]; a level-h plane is stored at 1 / 2^shift[h] of the
# map's resolution, plane_width[h] cells wide; (width, height): the padded map, pad: its
# margin in cells; evidence: how far after each optimistic plane its evidence twin starts
# (0 on a map without unknown cells: one set of planes is both) (see
# grids.PrecomputationGridStack).
Planes = namedtuple('Planes', 'flat shift plane_width pad width height evidence')
# base[h, i]: where the plane point i reads at level h starts; du, dv[row, i]: point i's
# cell offset at the angle of `row`; level h's rows start at row_start[h]; credit: the most
# a pose's optimistic score may exceed its evidence (raw: bnb.unknown_credit of the
# points taken as explained on unknown cells; a value, not a compiled-in constant, so a
# change reaches the cached kernels).
ScanTables = namedtuple('ScanTables', 'base du dv row_start credit')
# flags[offsets[h] + (v >> h) * width[h] + (u >> h)]: level-h block (u, v) holds a free cell.
FreeBlocks = namedtuple('FreeBlocks', 'flags offsets width')
# The map's size in cells, the number of leaf angles, the band's options: nodes bounded at
# or above verdict.keep_floor(the best leaf) are expanded (poor_fit: the lowest leaf fit
# that could be confident, verdict.confident_fit; 0 keeps the band below any best; poor_band
# 1 expands the band below a leaf at poor_fit while the best is under it, 0 only holds it:
# search.ThreadedSearch.run). The search prior: nodes with a cell
# within region_r cells of pixel (region_u, region_v), an angle within region_w angle steps of
# angle index region_a; region_r < 0 / region_w < 0: no bound.
SearchSpace = namedtuple('SearchSpace', 'map_w map_h n_angles keep_ratio min_confidence band_allowance '
                                       'poor_fit poor_band region_u region_v region_r region_a region_w')


@njit(cache=True, nogil=True, inline='always')
def plane_value(planes, start, h, x, y):
    """The value of the level-h plane starting at flat[start] at cell (x, y) of the padded
    map; 0 outside it (unsigned comparisons also catch x, y < 0)."""
    if uint64(x) < uint64(planes.width) and uint64(y) < uint64(planes.height):
        shift = planes.shift[h]
        return np.int64(planes.flat[uint64(start + (y >> shift) * planes.plane_width[h] + (x >> shift))])
    return np.int64(0)


@njit(cache=True, nogil=True)
def point_values(planes, tables, u, v, a, h, out, plane_shift):
    """Each point's term of the node's bound, into out: from the optimistic planes
    (plane_shift 0) or their evidence twins (plane_shift planes.evidence). (8 arguments:
    a compiled kernel takes no Python object cheaply, so a node comes as its numbers.)"""
    row = tables.row_start[h] + (a >> h)
    for i in range(tables.du.shape[1]):
        out[i] = plane_value(planes, tables.base[h, i] + plane_shift, h, u + planes.pad + tables.du[row, i],
                             v + planes.pad + tables.dv[row, i])


@njit(cache=True, nogil=True)
def node_bound(planes, tables, u, v, a, h, terms):
    """(bound, evidence bound) of node (u, v, a, h); at level 0 a pose's exact (score,
    evidence). terms: scratch, one per point. (7 arguments: a compiled kernel takes no
    Python object cheaply, so a node comes as its numbers.)"""
    point_values(planes, tables, u, v, a, h, terms, 0)
    total = terms.sum()
    if planes.evidence == 0:
        return total, total
    point_values(planes, tables, u, v, a, h, terms, planes.evidence)
    ev = terms.sum()
    return min(total, ev + tables.credit), ev


@njit(cache=True, nogil=True)
def child_bound(planes, tables, u, v, a, h, parent, parent_rest, ev_parent, ev_rest, floor):
    """A child's (bound, evidence bound), each point's terms capped by its parent's
    (parent[i], ev_parent[i]): every leaf under the child is under the parent, whose terms
    bound the leaf's for each point, so the capped sums are still bounds, and tighter ones.
    Capped terms never exceed the parent's, so as soon as the sums so far plus the parent's
    terms for the points left (parent_rest[i + 1], ev_rest[i + 1]) bound below `floor`, the
    child is pruned: the bound returned is then below `floor` too. Most children are
    pruned, most of them after a few points. (11 arguments: a compiled kernel takes no
    Python object cheaply, so the child comes as its numbers and its parent's terms as
    arrays.)"""
    row = tables.row_start[h] + (a >> h)
    total = 0
    if planes.evidence == 0:      # one set of planes (the default): half the reads, on the hot path
        for i in range(tables.du.shape[1]):
            total += min(plane_value(planes, tables.base[h, i], h, u + planes.pad + tables.du[row, i],
                                     v + planes.pad + tables.dv[row, i]), parent[i])
            if total + parent_rest[i + 1] < floor:
                return total, total
        return total, total
    credit = tables.credit
    ev = 0
    for i in range(tables.du.shape[1]):
        x = u + planes.pad + tables.du[row, i]
        y = v + planes.pad + tables.dv[row, i]
        total += min(plane_value(planes, tables.base[h, i], h, x, y), parent[i])
        ev += min(plane_value(planes, tables.base[h, i] + planes.evidence, h, x, y), ev_parent[i])
        if min(total + parent_rest[i + 1], ev + ev_rest[i + 1] + credit) < floor:
            return min(total, ev + credit), ev
    return min(total, ev + credit), ev


@njit(cache=True, nogil=True)
def node_bounds(planes, tables, tu, tv, ta, h):
    """The bounds of nodes (tu, tv, ta) at level h."""
    out = np.empty(len(tu), np.int64)
    terms = np.empty(tables.du.shape[1], np.int64)
    for k in range(len(tu)):
        out[k] = node_bound(planes, tables, tu[k], tv[k], ta[k], h, terms)[0]
    return out


@njit(cache=True, nogil=True, inline='always')
def child_node(free, space, u, v, a, h, c):
    """Child c (0..7: the 4 quarter blocks x the 2 halves of the angles) of node (u, v, a,
    h): (u, v, a) and whether it is searched at all - inside the map and the angles, on a
    block holding a free cell, holding a pose of the search prior. (7 arguments: a
    compiled kernel takes no Python object cheaply, so the node comes as its numbers.)"""
    half = 1 << (h - 1)
    cu = u + (c & 1) * half
    cv = v + ((c >> 1) & 1) * half
    ca = a + ((c >> 2) & 1) * half
    searched = (cu < space.map_w and cv < space.map_h and ca < space.n_angles
                and free.flags[free.offsets[h - 1] + (cv >> (h - 1)) * free.width[h - 1] + (cu >> (h - 1))] != 0
                and in_region(space, cu, cv, ca, h - 1))
    return cu, cv, ca, searched


@njit(cache=True, nogil=True, inline='always')
def in_region(space, u, v, a, h):
    """Whether node (u, v, a, h) holds a pose of the search prior."""
    size = 1 << h
    if space.region_r >= 0:
        dx = max(u - 0.5 - space.region_u, 0.0, space.region_u - (u + size - 0.5))
        dy = max(v - 0.5 - space.region_v, 0.0, space.region_v - (v + size - 0.5))
        if dx * dx + dy * dy > space.region_r * space.region_r:
            return False
    if space.region_w >= 0:
        ahead = (space.region_a - a) % space.n_angles      # from the node's first angle to the window's centre
        if ahead > size - 1 and min(ahead - (size - 1), space.n_angles - ahead) > space.region_w:
            return False
    return True


@njit(cache=True, nogil=True)
def region_mask(space, tu, tv, ta, h):
    """in_region for each node (tu, tv, ta) at level h."""
    out = np.empty(len(tu), np.bool_)
    for k in range(len(tu)):
        out[k] = in_region(space, tu[k], tv[k], ta[k], h)
    return out


@njit(cache=True, nogil=True)
def search_step(planes, tables, free, space, held, heap, shared_best, budget, per_level):
    """Resume the best-first search for at most `budget` expansions.

    heap: the pending nodes, (keys, nodes, size) as make_heap returns them. shared_best[0]:
    the best leaf evidence any thread's search has found (read before each expansion, raised
    when this one finds better; a stale read only prunes less). Every node whose bound
    reaches keep_floor(best) is expanded, best first; the search is over when the top of
    the heap is below that. Children and leaves reaching the floor of `held` (`space` with a
    band as wide or wider) are kept in the heap and returned, so the search can resume with
    it (search.Resume). The caller prunes the leaves by the final threshold. Counts
    expansions per level into per_level.
    Returns (expansions, done, leaves (m, 5): u, v, a, optimistic score, evidence, heap).
    (9 arguments: a compiled kernel takes no Python object cheaply, so the search comes as
    named tuples and arrays.)
    """
    keys, nodes, size = heap
    leaves = np.empty((64, 5), np.int64)
    n_leaves = 0
    n_points = tables.du.shape[1]
    parent = np.empty(n_points, np.int64)
    parent_rest = np.zeros(n_points + 1, np.int64)     # parent_rest[i]: sum of parent[i:]
    ev_parent = np.zeros(n_points, np.int64)           # the same from the evidence planes
    ev_rest = np.zeros(n_points + 1, np.int64)
    best = shared_best[0]
    floor = keep_floor(space, best, n_points)
    hold = keep_floor(held, best, n_points)
    expanded = 0
    done = False
    while expanded < budget:
        if shared_best[0] > best:      # a leaf another thread's search found
            best = shared_best[0]
            floor = keep_floor(space, best, n_points)
            hold = keep_floor(held, best, n_points)
        if size[0] == 0 or (keys[0] >> 3) < floor:      # the top node's bound (heap_key)
            done = True
            break
        _, h, u, v, a = heap_pop(keys, nodes, size)
        expanded += 1
        per_level[h] += 1
        point_values(planes, tables, u, v, a, h, parent, 0)
        for i in range(n_points - 1, -1, -1):
            parent_rest[i] = parent_rest[i + 1] + parent[i]
        if planes.evidence != 0:
            point_values(planes, tables, u, v, a, h, ev_parent, planes.evidence)
            for i in range(n_points - 1, -1, -1):
                ev_rest[i] = ev_rest[i + 1] + ev_parent[i]
        for c in range(8):
            cu, cv, ca, searched = child_node(free, space, u, v, a, h, c)
            if not searched:
                continue
            cb, ev = child_bound(planes, tables, cu, cv, ca, h - 1, parent, parent_rest, ev_parent, ev_rest, hold)
            if h == 1:      # a leaf: its exact scores (evidence <= optimistic: below hold, neither counts)
                if cb < hold:
                    continue
                if ev > best:     # (a raised hold stays <= best <= cb: the leaf is kept)
                    best = ev
                    floor = keep_floor(space, best, n_points)
                    hold = keep_floor(held, best, n_points)
                    if ev > shared_best[0]:
                        shared_best[0] = ev
                if n_leaves == leaves.shape[0]:
                    grown = np.empty((2 * n_leaves, 5), np.int64)
                    grown[:n_leaves] = leaves
                    leaves = grown
                leaves[n_leaves, 0] = cu
                leaves[n_leaves, 1] = cv
                leaves[n_leaves, 2] = ca
                leaves[n_leaves, 3] = cb
                leaves[n_leaves, 4] = ev
                n_leaves += 1
            elif cb >= hold:
                keys, nodes = heap_push(keys, nodes, size, heap_key(cb, h - 1), cu, cv, ca)
    return expanded, done, leaves[:n_leaves], (keys, nodes, size)


@njit(cache=True, nogil=True)
def dive(planes, tables, free, space, u, v, a, h):
    """A greedy descent from node (u, v, a, h) to a leaf: at each level the child (on a
    free block, in the search prior) with the highest bound. Returns the leaf's row (u,
    v, angle index, exact score), score -1 if no child qualified (not for a node on a
    free block in the prior: one of its children holds the same free cell). The search's
    first incumbent, so that it holds a leaf before its first slice ends. The leaf's row
    is (u, v, angle index, optimistic score, evidence). (8 arguments: a compiled kernel
    takes no Python object cheaply, so the node comes as its numbers.)"""
    terms = np.empty(tables.du.shape[1], np.int64)
    while h > 0:
        best_bound, best_ev, bu, bv, ba = np.int64(-1), np.int64(-1), u, v, a
        for c in range(8):
            cu, cv, ca, searched = child_node(free, space, u, v, a, h, c)
            if not searched:
                continue
            bound, ev = node_bound(planes, tables, cu, cv, ca, h - 1, terms)
            if bound > best_bound:
                best_bound, best_ev, bu, bv, ba = bound, ev, cu, cv, ca
        if best_bound < 0:
            return np.array([u, v, a, -1, -1], np.int64)
        u, v, a, h = bu, bv, ba, h - 1
        if h == 0:
            return np.array([u, v, a, best_bound, best_ev], np.int64)
    score, ev = node_bound(planes, tables, u, v, a, 0, terms)
    return np.array([u, v, a, score, ev], np.int64)


@njit(cache=True, nogil=True)
def offset_tables(theta, px, py):
    """Cell offsets (du, dv) of the points (px, py, laser frame, in cells) rotated by
    each angle of theta: the rows of ScanTables."""
    du = np.empty((len(theta), len(px)), np.int32)
    dv = np.empty((len(theta), len(px)), np.int32)
    for r in range(len(theta)):
        c, s = math.cos(theta[r]), math.sin(theta[r])
        for i in range(len(px)):
            x, y = image_point(0.0, 0.0, c, s, px[i], py[i])
            du[r, i] = round(x)
            dv[r, i] = round(y)
    return du, dv


def warm_up() -> None:
    """Compile (or load from numba's cache) the search kernels on a tiny problem, so a
    server pays it at start-up rather than in its first goal."""
    zeros = np.zeros(2, np.int64)
    widths = np.full(2, 4, np.int64)
    planes = Planes(np.zeros(64, np.uint8), zeros, widths, 0, 4, 4, 32)
    du = np.zeros((3, 1), np.int32)
    tables = ScanTables(np.zeros((2, 1), np.int64), du, du, np.array([0, 2], np.int64), 0)
    top = np.zeros((1, 4), np.int64)
    node_bounds(planes, tables, top[:, 0], top[:, 1], top[:, 2], 1)
    space = SearchSpace(2, 2, 2, 0.9, 0.5, 0.03, 0.4, 0.0, 0.0, 0.0, -1.0, 0.0, -1.0)
    free = FreeBlocks(np.ones(32, np.uint8), zeros, widths)
    search_step(planes, tables, free, space, space, make_heap(top, 1), np.zeros(1, np.int64), 10, np.zeros(2, np.int64))
    region_mask(space, top[:, 0], top[:, 1], top[:, 2], 1)
    dive(planes, tables, free, space, 0, 0, 0, 1)
    split_heap(*make_heap(top, 1))
    offset_tables(np.zeros(1), np.zeros(1), np.zeros(1))
