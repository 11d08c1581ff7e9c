"""bnb's heap of pending nodes: pops the highest key first, the level read back from the key;
built from top nodes in descending order it is the heap pushing them one by one builds."""
import numpy as np
import pytest

from global_loc.core.matchers.bnb.heap import empty_heap, heap_key, heap_pop, heap_push, make_heap, split_heap


def _drain(heap):
    keys, nodes, size = heap
    out = []
    while size[0] > 0:
        out.append(tuple(int(x) for x in heap_pop(keys, nodes, size)))
    return out


def test_the_heap_pops_by_key_and_gives_back_each_nodes_level_and_cell():
    rng = np.random.default_rng(0)
    keys, nodes, size = empty_heap(2)          # grows past its capacity
    pushed = []
    for _ in range(500):
        bound, level = int(rng.integers(0, 10_000)), int(rng.integers(0, 7))
        u, v, a = (int(x) for x in rng.integers(0, 2 ** 30, 3))
        keys, nodes = heap_push(keys, nodes, size, heap_key(bound, level), u, v, a)
        pushed.append((heap_key(bound, level), level, u, v, a))
    popped = _drain((keys, nodes, size))
    assert [p[0] for p in popped] == sorted((p[0] for p in pushed), reverse=True)
    assert sorted(popped) == sorted(pushed)    # each node's level and cell intact (int32, level in the key)


def test_top_nodes_in_descending_order_make_the_heap_their_pushes_make():
    rng = np.random.default_rng(1)
    top = np.stack([rng.integers(0, 5000, 300), rng.integers(0, 5000, 300), rng.integers(0, 40, 300),
                    rng.integers(0, 60, 300)], axis=1)        # bounds 0-59: many ties
    top = top[np.argsort(-top[:, 3], kind='stable')]
    keys, nodes, size = make_heap(top, 6)
    pk, pn, ps = empty_heap(len(top))
    for u, v, a, bound in top:
        pk, pn = heap_push(pk, pn, ps, heap_key(bound, 6), u, v, a)
    assert size[0] == ps[0] == len(top)
    np.testing.assert_array_equal(keys[:len(top)], pk[:len(top)])
    np.testing.assert_array_equal(nodes[:len(top)], pn[:len(top)])
    halves = split_heap(keys, nodes, size)
    assert sorted(_drain(halves[0]) + _drain(halves[1])) == sorted(_drain(make_heap(top, 6)))


def test_make_heap_refuses_nodes_out_of_order():
    top = np.array([[0, 0, 0, 5], [1, 0, 0, 7]], np.int64)
    with pytest.raises(ValueError, match='descending'):
        make_heap(top, 6)
