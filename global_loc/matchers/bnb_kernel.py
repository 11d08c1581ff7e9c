"""Compiled (numba) inner loops of the branch-and-bound matcher: a node's bound, and the
best-first search itself. numpy cannot walk a search tree one node at a time fast
enough, and batching nodes for numpy (the previous design) wasted expansions because its
pruning threshold lagged behind the best leaf: on real logs this kernel needs 5-20x
fewer expansions and does each ~10x faster. Numbers only here: the geometry (angle
tables, which grid each point reads) is prepared in bnb.py. Compiled on first use and
cached on disk (numba cache=True), so only a machine's first run pays the ~15 s.

A node is (u, v, a, h): cells u .. u + 2^h - 1, v .. v + 2^h - 1 of the map, angle
indices a .. a + 2^h - 1. Its bound is the sum over the scan's points of the point's
plane (the one widened for its range, bnb.PrecomputationGridStack.grid_ids) at the
point's cell, the point rotated by the node's middle angle (row row_start[h] + a >> h
of the offset tables). Sums are integers (planes are uint8).

The planes are one flat array (`flat`): point i at level h reads the plane starting at
base[h, i], at (y >> shift[h]) * plane_width[h] + (x >> shift[h]) (x, y: the cell in the
padded map; see PrecomputationGridStack), with unsigned bounds tests: numba's 3-d
indexing with signed indices (wraparound) cost twice as much per point.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, uint64


@njit(cache=True, nogil=True, inline='always')
def plane_value(flat, start, shift, plane_width, width, height, x, y):
    """The value of the plane starting at flat[start] at cell (x, y) of the padded map;
    0 outside it (unsigned comparisons also catch x, y < 0)."""
    if uint64(x) < uint64(width) and uint64(y) < uint64(height):
        return np.int64(flat[uint64(start + (y >> shift) * plane_width + (x >> shift))])
    return np.int64(0)


@njit(cache=True, nogil=True)
def point_values(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height, u, v, a, h, out):
    """Each point's term of the node's bound, into out."""
    row = row_start[h] + (a >> h)
    for i in range(du_all.shape[1]):
        out[i] = plane_value(flat, base[h, i], shift[h], plane_width[h], width, height,
                             u + pad + du_all[row, i], v + pad + dv_all[row, i])


@njit(cache=True, nogil=True)
def child_bound(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height, u, v, a, h, parent,
                parent_rest, floor):
    """A child's bound, each point's term capped by its parent's (parent[i]): every leaf
    under the child is under the parent, whose term bounds the leaf's for each point,
    so the capped sum is still a bound, and a tighter one. Capped terms never exceed the
    parent's, so as soon as the sum so far plus the parent's terms for the points left
    (parent_rest[i + 1]) is below `floor`, the child is pruned: the value returned is
    then below `floor` too. Most children are pruned, most of them after a few points."""
    row = row_start[h] + (a >> h)
    total = 0
    for i in range(du_all.shape[1]):
        total += min(plane_value(flat, base[h, i], shift[h], plane_width[h], width, height,
                                 u + pad + du_all[row, i], v + pad + dv_all[row, i]), parent[i])
        if total + parent_rest[i + 1] < floor:
            return total
    return total


@njit(cache=True, nogil=True)
def node_bounds(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height, tu, tv, ta, h):
    """The bounds of nodes (tu, tv, ta) at level h: the sums of their points' terms."""
    out = np.empty(len(tu), np.int64)
    terms = np.empty(du_all.shape[1], np.int64)
    for k in range(len(tu)):
        point_values(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height,
                     tu[k], tv[k], ta[k], h, terms)
        out[k] = terms.sum()
    return out


# Counters that one thread writes at every node (a heap's size, expansions per level) are
# PAD int64s long, only the first few used: two threads' counters in one 64-byte cache
# line would make each write wait for the other core (false sharing; measured: each
# thread's expansions took twice as long).
PAD = 16

# The pending nodes: a binary max-heap in arrays. heapq on a numba typed List costs
# ~1.5 us per push or pop (every item access is a call into the list's C code), which
# was ~40% of a search; these take ~0.1 us. keys[k] = bound x 8 + 7 - level: the highest
# bound first, the deeper node first among equal bounds (reaching leaves sooner raises
# the pruning threshold sooner). nodes[k] = (level, u, v, a). size[0]: the heap's size.
@njit(cache=True, nogil=True, inline='always')
def heap_key(bound, level):
    """A node's key; key >> 3 is its bound (levels < 8)."""
    return bound * 8 + 7 - level


@njit(cache=True, nogil=True)
def heap_push(keys, nodes, size, key, h, u, v, a):
    """Push a node; returns (keys, nodes), grown when full."""
    n = size[0]
    if n == keys.shape[0]:
        grown_keys = np.empty(2 * n + 16, np.int64)
        grown_keys[:n] = keys
        grown_nodes = np.empty((2 * n + 16, 4), np.int64)
        grown_nodes[:n] = nodes
        keys, nodes = grown_keys, grown_nodes
    i = n
    while i > 0:
        up = (i - 1) >> 1
        if keys[up] >= key:
            break
        keys[i] = keys[up]
        nodes[i] = nodes[up]
        i = up
    keys[i] = key
    nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i, 3] = h, u, v, a
    size[0] = n + 1
    return keys, nodes


@njit(cache=True, nogil=True)
def heap_pop(keys, nodes, size):
    """Remove the top node; returns (key, level, u, v, a)."""
    top_key, h, u, v, a = keys[0], nodes[0, 0], nodes[0, 1], nodes[0, 2], nodes[0, 3]
    n = size[0] - 1
    size[0] = n
    if n > 0:
        key = keys[n]
        i = 0
        while True:
            child = 2 * i + 1
            if child >= n:
                break
            if child + 1 < n and keys[child + 1] > keys[child]:
                child += 1
            if keys[child] <= key:
                break
            keys[i] = keys[child]
            nodes[i] = nodes[child]
            i = child
        keys[i] = key
        nodes[i] = nodes[n]
    return top_key, h, u, v, a


@njit(cache=True, nogil=True)
def empty_heap(capacity):
    """(keys, nodes, size) with room for `capacity` nodes (more grow it)."""
    return np.empty(capacity + 16, np.int64), np.empty((capacity + 16, 4), np.int64), np.zeros(PAD, np.int64)


@njit(cache=True, nogil=True)
def make_heap(top_nodes, level):
    """A heap of the top-level nodes, rows (u, v, a, bound): (keys, nodes, size)."""
    n = top_nodes.shape[0]
    keys, nodes, size = empty_heap(n)
    for k in range(n):
        keys, nodes = heap_push(keys, nodes, size, heap_key(top_nodes[k, 3], level), level,
                                top_nodes[k, 0], top_nodes[k, 1], top_nodes[k, 2])
    return keys, nodes, size


@njit(cache=True, nogil=True)
def split_heap(keys, nodes, size):
    """Deal a heap's nodes alternately into two new heaps (for a thread whose own ran out)."""
    n = size[0]
    out = []
    for part in range(2):
        pk, pn, ps = empty_heap((n - part + 1) // 2)
        for i in range(part, n, 2):
            pk, pn = heap_push(pk, pn, ps, keys[i], nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i, 3])
        out.append((pk, pn, ps))
    return out[0], out[1]


@njit(cache=True, nogil=True)
def search_step(flat, free_blocks, free_offsets, free_width, base, du_all, dv_all, row_start, shift, plane_width,
                pad, width, height, map_w, map_h, n_angles, keep, heap, shared_best, budget, per_level):
    """Resume the best-first search for at most `budget` expansions.

    heap: the pending nodes, (keys, nodes, size) as make_heap returns them. shared_best[0]:
    the best leaf score any thread's search has found (read before each expansion,
    raised when this one finds better; a stale read only prunes less). Best first
    expands no node whose bound is below the best leaf, so it expands the fewest nodes
    any search with these bounds can (a depth-first walk wanders through whole subtrees under a low early
    threshold). Every node whose bound reaches keep x best is expanded; the search is
    over when the top of the heap is below that. Leaves (level 0, exact scores)
    reaching keep x best when scored are returned; the caller prunes them by the final
    threshold. Counts expansions per level into per_level.
    Returns (expansions, done, leaves (m, 4): u, v, a, score, heap).
    """
    keys, nodes, size = heap
    leaves = np.empty((64, 4), np.int64)
    n_leaves = 0
    n_points = du_all.shape[1]
    parent = np.empty(n_points, np.int64)
    parent_rest = np.zeros(n_points + 1, np.int64)     # parent_rest[i]: sum of parent[i:]
    best = shared_best[0]
    expanded = 0
    done = False
    while expanded < budget:
        if shared_best[0] > best:      # a leaf another thread's search found
            best = shared_best[0]
        if size[0] == 0 or (keys[0] >> 3) < keep * best:      # the top node's bound (heap_key)
            done = True
            break
        _, h, u, v, a = heap_pop(keys, nodes, size)
        expanded += 1
        per_level[h] += 1
        point_values(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height, u, v, a, h, parent)
        for i in range(n_points - 1, -1, -1):
            parent_rest[i] = parent_rest[i + 1] + parent[i]
        half = 1 << (h - 1)
        for c in range(8):     # the 4 quarter blocks x the 2 halves of the angles
            cu = u + (c & 1) * half
            cv = v + ((c >> 1) & 1) * half
            ca = a + ((c >> 2) & 1) * half
            if cu >= map_w or cv >= map_h or ca >= n_angles:
                continue
            if free_blocks[free_offsets[h - 1] + (cv >> (h - 1)) * free_width[h - 1] + (cu >> (h - 1))] == 0:
                continue
            cb = child_bound(flat, base, du_all, dv_all, row_start, shift, plane_width, pad, width, height,
                             cu, cv, ca, h - 1, parent, parent_rest, int(math.ceil(keep * best)))
            if h == 1:      # a leaf: its exact score
                if cb > best:
                    best = cb
                    if cb > shared_best[0]:
                        shared_best[0] = cb
                if cb >= keep * best:
                    if n_leaves == leaves.shape[0]:
                        grown = np.empty((2 * n_leaves, 4), np.int64)
                        grown[:n_leaves] = leaves
                        leaves = grown
                    leaves[n_leaves, 0] = cu
                    leaves[n_leaves, 1] = cv
                    leaves[n_leaves, 2] = ca
                    leaves[n_leaves, 3] = cb
                    n_leaves += 1
            elif cb >= keep * best:
                keys, nodes = heap_push(keys, nodes, size, heap_key(cb, h - 1), h - 1, cu, cv, ca)
    return expanded, done, leaves[:n_leaves], (keys, nodes, size)


@njit(cache=True, nogil=True)
def offset_tables(theta, px, py):
    """Cell offsets (du, dv) of the points (px, py, laser frame, in cells) rotated by
    each angle of theta: rows of the tables node_bound reads. dv: rows grow downwards."""
    du = np.empty((len(theta), len(px)), np.int32)
    dv = np.empty((len(theta), len(px)), np.int32)
    for r in range(len(theta)):
        c, s = math.cos(theta[r]), math.sin(theta[r])
        for i in range(len(px)):
            du[r, i] = round(c * px[i] - s * py[i])
            dv[r, i] = round(-(s * px[i] + c * py[i]))
    return du, dv


@njit(cache=True, nogil=True)
def field_means(field, poses, px, py):
    """Per pose (u, v, yaw: continuous pixel position, grid-frame heading): the mean of
    the field, bilinearly interpolated (zero outside the map), at the points (px, py,
    laser frame, in cells). The refinement's and the covariance's score."""
    height, width = field.shape
    out = np.empty(poses.shape[0])
    for k in range(poses.shape[0]):
        c, s = math.cos(poses[k, 2]), math.sin(poses[k, 2])
        total = 0.0
        for i in range(len(px)):
            x = poses[k, 0] + c * px[i] - s * py[i]
            y = poses[k, 1] - (s * px[i] + c * py[i])
            x0, y0 = math.floor(x), math.floor(y)
            fx, fy = x - x0, y - y0
            ix, iy = int(x0), int(y0)
            for dy in range(2):
                for dx in range(2):
                    xx, yy = ix + dx, iy + dy
                    if 0 <= xx < width and 0 <= yy < height:
                        total += field[yy, xx] * (fx if dx else 1.0 - fx) * (fy if dy else 1.0 - fy)
        out[k] = total / max(len(px), 1)
    return out


@njit(cache=True, nogil=True)
def see_through(occupied, poses, angles, lengths):
    """Per pose (u, v, yaw: pixel position, grid-frame heading): how many of the rays
    (laser-frame angles, lengths in cells) pass an occupied cell. Walks each ray in
    half-cell steps from the laser and stops at the first occupied cell."""
    height, width = occupied.shape
    out = np.zeros(poses.shape[0], np.int64)
    for k in range(poses.shape[0]):
        for i in range(len(angles)):
            c = math.cos(poses[k, 2] + angles[i])
            s = math.sin(poses[k, 2] + angles[i])
            t = 0.5
            while t < lengths[i]:
                x = int(round(poses[k, 0] + c * t))
                y = int(round(poses[k, 1] - s * t))     # rows grow downwards
                if 0 <= x < width and 0 <= y < height and occupied[y, x]:
                    out[k] += 1
                    break
                t += 0.5
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel on a tiny problem, so a server
    pays it at start-up rather than in its first goal."""
    grids = np.zeros((1, 4, 4), np.uint8)
    free = np.ones((2, 4, 4), np.uint8)
    base = np.zeros((2, 1), np.int64)
    du = np.zeros((3, 1), np.int32)
    row_start = np.array([0, 2], np.int64)
    top = np.zeros((1, 4), np.int64)
    zeros = np.zeros(2, np.int64)
    widths = np.full(2, 4, np.int64)
    node_bounds(grids.ravel(), base, du, du, row_start, zeros, widths, 0, 4, 4, top[:, 0], top[:, 1], top[:, 2], 1)
    search_step(grids.ravel(), free.ravel(), zeros, widths, base, du, du, row_start, zeros, widths, 0, 4, 4,
                2, 2, 2, 0.9, make_heap(top, 1), np.zeros(1, np.int64), 10,
                np.zeros(2, np.int64))
    split_heap(*make_heap(top, 1))
    see_through(grids[0], np.zeros((1, 3)), np.zeros(1), np.ones(1))
    offset_tables(np.zeros(1), np.zeros(1), np.zeros(1))
    field_means(np.zeros((2, 2), np.float32), np.zeros((1, 3)), np.zeros(1), np.zeros(1))
