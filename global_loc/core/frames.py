"""A tree of fixed frames - a URDF's fixed joints, /tf_static, a recording's unchanging
tf - and the pose of one frame in another composed along it: the one place where chains
of mountings are composed.

`parents` maps a child frame to (its parent frame, 4x4 parent_T_child), as tf keeps its
tree: every frame has at most one parent, the newest transform received for it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .transform import rotation_of_quaternion


def transform_matrix(translation, quaternion) -> np.ndarray:
    """4x4 homogeneous transform of a translation (x, y, z) and a rotation quaternion
    (x, y, z, w); ValueError when either is not finite or the quaternion is zero."""
    t = np.asarray(translation, dtype=float)
    if t.shape != (3,) or not np.isfinite(t).all():
        raise ValueError(f'a translation must be three finite numbers, got {t.tolist()}')
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation_of_quaternion(*quaternion), t
    return m


def path_to_root(parents: dict, frame: str) -> list[str]:
    """`frame`, its parent, the parent's parent, ... (a loop in the tree ends the walk)."""
    chain = [frame]
    while chain[-1] in parents and parents[chain[-1]][0] not in chain:
        chain.append(parents[chain[-1]][0])
    return chain


def root_T(parents: dict, chain: list[str]) -> np.ndarray:
    """The pose of chain[0] in chain[-1], composing each frame's transform to its parent."""
    m = np.eye(4)
    for frame in reversed(chain[:-1]):
        m = m @ parents[frame][1]
    return m


@dataclass(frozen=True)
class Chain:
    """`frame` on `base` through the tree."""
    base_T_frame: np.ndarray       # 4x4
    frames: tuple                  # base ... frame, through their nearest common ancestor
    composed: tuple                # the child frames whose transforms to their parents it composes


def compose(parents: dict, base: str, frame: str) -> Optional[Chain]:
    """The pose of `frame` in `base` through their nearest common ancestor; None when the
    tree does not link them."""
    up_from_frame, up_from_base = path_to_root(parents, frame), path_to_root(parents, base)
    common = next((f for f in up_from_frame if f in up_from_base), None)
    if common is None:
        return None
    frame_chain = up_from_frame[:up_from_frame.index(common) + 1]
    base_chain = up_from_base[:up_from_base.index(common) + 1]
    base_T_frame = np.linalg.inv(root_T(parents, base_chain)) @ root_T(parents, frame_chain)
    return Chain(base_T_frame, tuple(base_chain + frame_chain[-2::-1]), tuple(frame_chain[:-1] + base_chain[:-1]))
