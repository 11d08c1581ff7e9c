"""A URDF's fixed joints, read with xml.etree (no ROS): where each link sits on its
parent, and where a sensor frame sits on the base, the joints' origins composed
(core/frames.py). These are the transforms robot_state_publisher puts on /tf_static. Also
the URDF's bodies alone, without the links that are only frames, for a physics engine."""
from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass

from ..core.frames import path_to_root, root_T
from ..core.mount3d import Mount3D, Mount3DError


class UrdfError(ValueError):
    """The URDF cannot be read, or does not link a frame to the base by fixed joints."""


@dataclass(frozen=True)
class FixedJoint:
    name: str
    parent: str              # the parent link (its frame)
    child: str               # the child link
    origin: Mount3D          # the child on the parent: <origin xyz="..." rpy="..."/>


def fixed_joints(path: str) -> dict:
    """Every fixed joint of the URDF at `path`, by its child link; UrdfError when the file
    cannot be parsed or a fixed joint lacks its parent, child or a readable origin."""
    try:
        robot = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as e:
        raise UrdfError(f'{path}: {e}') from None
    joints = {}
    for joint in robot.iter('joint'):
        if joint.get('type') != 'fixed':
            continue
        name = joint.get('name', '?')
        parent, child, origin = joint.find('parent'), joint.find('child'), joint.find('origin')
        if parent is None or child is None or not parent.get('link') or not child.get('link'):
            raise UrdfError(f'{path}: fixed joint {name} needs <parent link=...> and <child link=...>')
        joints[child.get('link')] = FixedJoint(name, parent.get('link'), child.get('link'),
                                               _origin(origin, f'{path}: fixed joint {name}'))
    return joints


def bodies_only(path: str) -> str:
    """The URDF at `path` as text without its frame-only links (no <inertial>: a sensor's
    frame) and the joints to them. A physics engine would give such a link a mass of its
    own (pybullet: 1 kg); a frame has none. UrdfError when a frame-only link has a child
    with a body (what it holds would be lost)."""
    try:
        tree = ElementTree.parse(path)
    except (OSError, ElementTree.ParseError) as e:
        raise UrdfError(f'{path}: {e}') from None
    robot = tree.getroot()
    frames = {link.get('name') for link in robot.findall('link') if link.find('inertial') is None}
    for joint in robot.findall('joint'):
        parent, child = joint.find('parent'), joint.find('child')
        if parent is not None and child is not None and parent.get('link') in frames:
            if child.get('link') not in frames:
                raise UrdfError(f'{path}: link {child.get("link")} has a body but hangs on the frame-only link '
                                f'{parent.get("link")} (give that one an <inertial>)')
        if child is not None and child.get('link') in frames:
            robot.remove(joint)
    for link in robot.findall('link'):
        if link.get('name') in frames:
            robot.remove(link)
    return ElementTree.tostring(robot, encoding='unicode')


def _origin(element, where: str) -> Mount3D:
    """A joint's <origin> (absent, or an absent attribute: zeros, as URDF has it)."""
    if element is None:
        return Mount3D()
    xyz, rpy = element.get('xyz', '0 0 0').split(), element.get('rpy', '0 0 0').split()
    try:
        if len(xyz) != 3 or len(rpy) != 3:
            raise ValueError('not three numbers')
        return Mount3D.from_values(xyz + rpy)
    except (ValueError, Mount3DError):
        raise UrdfError(f'{where}: <origin> needs xyz and rpy of three finite numbers each, got '
                        f'xyz={element.get("xyz")!r} rpy={element.get("rpy")!r}') from None


def _up_to(joints: dict, base: str, frame: str) -> list:
    """`frame`, its parent, ... up to `base`; UrdfError when `base` is not above `frame`."""
    chain = path_to_root({child: (joint.parent, None) for child, joint in joints.items()}, frame)
    if base not in chain:
        raise UrdfError(f'no chain of fixed joints from {base} down to {frame} (up from {frame}: '
                        f'{" -> ".join(chain)})')
    return chain[:chain.index(base) + 1]


def joints_to(joints: dict, base: str, frame: str) -> list:
    """The fixed joints from `base` down to `frame`, base first; UrdfError when `frame` does
    not hang below `base` by fixed joints."""
    return [joints[child] for child in reversed(_up_to(joints, base, frame)[:-1])]


def mount_of(joints: dict, base: str, frame: str) -> Mount3D:
    """`frame` on `base`: the origins of the fixed joints between them composed."""
    parents = {child: (joint.parent, joint.origin.matrix()) for child, joint in joints.items()}
    return Mount3D.from_matrix(root_T(parents, _up_to(joints, base, frame)))
