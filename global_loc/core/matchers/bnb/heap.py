"""The search's pending nodes: a binary max-heap in flat arrays, compiled (numba), one per
search thread (kernels.search_step pops and pushes; search.py builds and splits them)."""
from __future__ import annotations

import numpy as np
from numba import njit

# Counters one thread writes at every node (heap size, expansions per level) are PAD int64s
# long: two threads' counters in one 64-byte cache line would make each write wait (false sharing).
PAD = 16

# Flat arrays, not heapq on a numba typed List (which calls into the list's C code for every
# item access). keys[k] = bound x 8 + 7 - level: the highest bound first, the deeper node first
# among equal bounds (reaching leaves sooner raises the pruning threshold sooner). nodes[k] =
# (u, v, a) as int32, the level read from the key: 20 bytes a node, not 40 (a search on a 36
# Mcell map holds ~2 million). size[0]: the heap's size.
@njit(cache=True, nogil=True, inline='always')
def heap_key(bound, level):
    """A node's key; key >> 3 is its bound (levels < 8)."""
    return bound * 8 + 7 - level


@njit(cache=True, nogil=True)
def heap_push(keys, nodes, size, key, u, v, a):
    """Push a node (its level is in its key); returns (keys, nodes), grown when full. (7
    arguments: a compiled kernel takes no Python object cheaply, so the heap comes as its
    arrays and the node as its numbers.)"""
    n = size[0]
    if n == keys.shape[0]:
        grown_keys = np.empty(2 * n + 16, np.int64)
        grown_keys[:n] = keys
        grown_nodes = np.empty((2 * n + 16, 3), np.int32)
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
    nodes[i, 0], nodes[i, 1], nodes[i, 2] = u, v, a
    size[0] = n + 1
    return keys, nodes


@njit(cache=True, nogil=True)
def heap_pop(keys, nodes, size):
    """Remove the top node; returns (key, level, u, v, a)."""
    top_key, u, v, a = keys[0], np.int64(nodes[0, 0]), np.int64(nodes[0, 1]), np.int64(nodes[0, 2])
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
    return top_key, 7 - (top_key & 7), u, v, a


@njit(cache=True, nogil=True)
def empty_heap(capacity):
    """(keys, nodes, size) with room for `capacity` nodes (more grow it)."""
    return np.empty(capacity + 16, np.int64), np.empty((capacity + 16, 3), np.int32), np.zeros(PAD, np.int64)


@njit(cache=True, nogil=True)
def make_heap(top_nodes, level):
    """A heap of the top-level nodes, rows (u, v, a, bound) in descending bound order, which
    is a max-heap as it stands: the array pushing them one by one would build, without the
    pushes (~0.03 s a search on a 36 Mcell map's 350 000 top nodes): (keys, nodes, size)."""
    n = top_nodes.shape[0]
    keys, nodes, size = empty_heap(n)
    for k in range(n):
        if k > 0 and top_nodes[k, 3] > top_nodes[k - 1, 3]:
            raise ValueError('make_heap needs the nodes in descending bound order')
        keys[k] = heap_key(top_nodes[k, 3], level)
        nodes[k, 0], nodes[k, 1], nodes[k, 2] = top_nodes[k, 0], top_nodes[k, 1], top_nodes[k, 2]
    size[0] = n
    return keys, nodes, size


@njit(cache=True, nogil=True)
def split_heap(keys, nodes, size):
    """Deal a heap's nodes alternately into two new heaps (for a thread whose own ran out)."""
    n = size[0]
    out = []
    for part in range(2):
        pk, pn, ps = empty_heap((n - part + 1) // 2)
        for i in range(part, n, 2):
            pk, pn = heap_push(pk, pn, ps, keys[i], nodes[i, 0], nodes[i, 1], nodes[i, 2])
        out.append((pk, pn, ps))
    return out[0], out[1]
