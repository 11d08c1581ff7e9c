"""Compiled (numba) inner loops of the branch-and-bound matcher: a node's bound, and the
best-first search itself. numpy cannot walk a search tree one node at a time fast
enough, and batching nodes for numpy (the previous design) wasted expansions because its
pruning threshold lagged behind the best leaf: on real logs this kernel needs 5-20x
fewer expansions and does each ~10x faster. Numbers only here: the geometry (angle
tables, which grid each point reads) is prepared in bnb.py. Compiled on first use and
cached on disk (numba cache=True), so only a machine's first run pays the ~15 s.

A node is (u, v, a, h): cells u .. u + 2^h - 1, v .. v + 2^h - 1 of the map, angle
indices a .. a + 2^h - 1. Its bound is the sum over the scan's points of
grids[gid[h, i]] at the point's cell, the point rotated by the node's middle angle
(row row_start[h] + a >> h of the offset tables). Sums are integers (grids are uint8).
"""
from __future__ import annotations

import heapq
import math

import numpy as np
from numba import njit
from numba.typed import List


@njit(cache=True, nogil=True)
def node_bound(grids, gid, du_all, dv_all, row_start, pad, u, v, a, h, floor=0):
    """The node's bound; or, as soon as the points left cannot lift it to `floor`, some
    value below `floor` (the caller prunes it either way: most children are pruned, and
    stopping early saves most of their cost)."""
    row = row_start[h] + (a >> h)
    _, height, width = grids.shape
    bu, bv = u + pad, v + pad
    n = du_all.shape[1]
    total = 0
    for i in range(n):
        x = bu + du_all[row, i]
        y = bv + dv_all[row, i]
        # Outside the padded grids every grid is zero.
        if 0 <= x < width and 0 <= y < height:
            total += grids[gid[h, i], y, x]
        if (i & 7) == 7 and total + 255 * (n - 1 - i) < floor:
            return total
    return total


@njit(cache=True, nogil=True)
def node_bounds(grids, gid, du_all, dv_all, row_start, pad, tu, tv, ta, h):
    out = np.empty(len(tu), np.int64)
    for k in range(len(tu)):
        out[k] = node_bound(grids, gid, du_all, dv_all, row_start, pad, tu[k], tv[k], ta[k], h)
    return out


@njit(cache=True, nogil=True)
def search_step(grids, free_blocks, gid, du_all, dv_all, row_start, pad, map_w, map_h, n_angles, keep,
                heap, best, budget, per_level):
    """Resume the best-first search for at most `budget` expansions.

    heap: pending nodes as (-bound, level, u, v, a) (heapq order: highest bound first,
    the deeper node first among equal bounds). Best first expands no node whose bound
    is below the best leaf, so it expands the fewest nodes any search with these
    bounds can (a depth-first walk wanders through whole subtrees under a low early
    threshold). Every node whose bound reaches keep x best is expanded; the search is
    over when the top of the heap is below that. Leaves (level 0, exact scores)
    reaching keep x best when scored are returned; the caller prunes them by the final
    threshold. Counts expansions per level into per_level.
    Returns (best, expansions, done, leaves (m, 4): u, v, a, score).
    """
    leaves = np.empty((64, 4), np.int64)
    n_leaves = 0
    expanded = 0
    done = False
    while expanded < budget:
        if len(heap) == 0 or -heap[0][0] < keep * best:
            done = True
            break
        neg_b, h, u, v, a = heapq.heappop(heap)
        expanded += 1
        per_level[h] += 1
        half = 1 << (h - 1)
        for c in range(8):     # the 4 quarter blocks x the 2 halves of the angles
            cu = u + (c & 1) * half
            cv = v + ((c >> 1) & 1) * half
            ca = a + ((c >> 2) & 1) * half
            if cu >= map_w or cv >= map_h or ca >= n_angles:
                continue
            if free_blocks[h - 1, cv + pad, cu + pad] == 0:
                continue
            cb = node_bound(grids, gid, du_all, dv_all, row_start, pad, cu, cv, ca, h - 1,
                            int(math.ceil(keep * best)))
            if h == 1:      # a leaf: its exact score
                if cb > best:
                    best = cb
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
                heapq.heappush(heap, (-cb, h - 1, cu, cv, ca))
    return best, expanded, done, leaves[:n_leaves]


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


@njit(cache=True, nogil=True)
def make_heap(top_nodes, level):
    """A heap of the top-level nodes, rows (u, v, a, bound)."""
    heap = List()      # typed: it stays compiled between calls (a Python list is re-checked each call)
    for k in range(top_nodes.shape[0]):
        heap.append((-top_nodes[k, 3], level, top_nodes[k, 0], top_nodes[k, 1], top_nodes[k, 2]))
    heapq.heapify(heap)
    return heap


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel on a tiny problem, so a server
    pays it at start-up rather than in its first goal."""
    grids = np.zeros((1, 4, 4), np.uint8)
    free = np.ones((2, 4, 4), np.uint8)
    gid = np.zeros((2, 1), np.int64)
    du = np.zeros((3, 1), np.int32)
    row_start = np.array([0, 2], np.int64)
    top = np.zeros((1, 4), np.int64)
    node_bounds(grids, gid, du, du, row_start, 0, top[:, 0], top[:, 1], top[:, 2], 1)
    search_step(grids, free, gid, du, du, row_start, 0, 2, 2, 2, 0.9, make_heap(top, 1), 0, 10,
                np.zeros(2, np.int64))
    see_through(grids[0], np.zeros((1, 3)), np.zeros(1), np.ones(1))
    offset_tables(np.zeros(1), np.zeros(1), np.zeros(1))
    field_means(np.zeros((2, 2), np.float32), np.zeros((1, 3)), np.zeros(1), np.zeros(1))
