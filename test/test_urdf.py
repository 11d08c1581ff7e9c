"""The URDF's fixed joints (io/urdf.py) and the simulator's mountings read from them
(sim/robot.py): one source for the rays the simulator casts and the /tf_static it publishes."""
import math

import numpy as np
import pytest

from conftest import needs_pybullet
from global_loc.core.mount3d import Mount3D
from global_loc.core.transform import Rigid2D
from global_loc.io.urdf import UrdfError, bodies_only, fixed_joints, joints_to, mount_of
from global_loc.sim import robot


def assert_same_mount(a: Mount3D, b: Mount3D) -> None:
    assert np.allclose(a.matrix(), b.matrix(), atol=1e-12), (a, b)


def test_the_urdfs_joints_give_each_sensor_frame_the_simulator_stamps():
    joints = fixed_joints(robot.URDF)
    for frame in (robot.LASER_FRAME, robot.REAR_LASER_FRAME, robot.LIDAR_FRAME):
        assert [j.parent for j in joints_to(joints, robot.BASE_FRAME, frame)] == [robot.BASE_FRAME], frame
    assert_same_mount(robot.FRONT_LASER_MOUNT, Mount3D(0.16, 0.0, 0.30))
    assert_same_mount(robot.REAR_LASER_MOUNT, Mount3D(-0.25, 0.0, 0.30, 0.0, 0.0, math.pi))
    assert_same_mount(robot.LIDAR_MOUNT, Mount3D(0.0, 0.0, 0.5))
    assert 'left_wheel' not in joints        # a continuous joint moves: not a mounting


@needs_pybullet
def test_the_simulators_rays_leave_from_the_urdfs_mountings(office_map):
    from global_loc.sim.laser import LaserConfig
    from global_loc.sim.lidar3d import Lidar3DConfig
    from global_loc.sim.simulator import BASE_T_LASER, LASER_HEIGHT, Simulator
    sim = Simulator(office_map, LaserConfig(), rear_laser=LaserConfig(), lidar=Lidar3DConfig())
    try:
        import pybullet as p
        assert p.getNumJoints(sim.robot, physicsClientId=sim.client) == 4     # wheels, caster, laser: bodies only
        pose = Rigid2D(3.0, 4.0, 0.7)
        sim.place(pose)
        # the front laser is cast from pybullet's laser link, which pybullet places by laser_joint
        laser = sim.laser_pose()
        assert laser.distance_to(pose * robot.FRONT_LASER_MOUNT.upright())[0] < 1e-3
        assert laser.distance_to(pose * BASE_T_LASER)[1] < 1e-3 and LASER_HEIGHT == robot.FRONT_LASER_MOUNT.z
        # the rear laser and the lidar are cast from the mountings sim/robot.py read
        for mount in (robot.REAR_LASER_MOUNT, robot.LIDAR_MOUNT):
            position, rotation = sim._sensor_pose(mount)
            world_T_base = Mount3D.planar(pose).matrix()
            expected = world_T_base @ mount.matrix()
            assert np.allclose(position, expected[:3, 3], atol=1e-3) and np.allclose(rotation, expected[:3, :3],
                                                                                      atol=1e-3)
    finally:
        sim.close()


MAST_URDF = """<?xml version="1.0"?>
<robot name="mast">
  <link name="base_footprint"/><link name="base_link"/><link name="mast"/><link name="lidar"/><link name="wheel"/>
  <joint name="base_joint" type="fixed"><parent link="base_footprint"/><child link="base_link"/>
    <origin xyz="0 0 0.1"/></joint>
  <joint name="mast_joint" type="fixed"><parent link="base_link"/><child link="mast"/>
    <origin xyz="0.2 0.1 0.3" rpy="0 0 1.5707963267948966"/></joint>
  <joint name="lidar_joint" type="fixed"><parent link="mast"/><child link="lidar"/>
    <origin xyz="0.05 0 0.4" rpy="3.141592653589793 0.2 0"/></joint>
  <joint name="wheel_joint" type="continuous"><parent link="base_link"/><child link="wheel"/>
    <origin xyz="0 0.2 0"/></joint>
</robot>
"""


def test_a_chain_of_fixed_joints_composes_parent_by_parent(tmp_path):
    path = tmp_path / 'mast.urdf'
    path.write_text(MAST_URDF)
    joints = fixed_joints(str(path))
    assert [j.name for j in joints_to(joints, 'base_link', 'lidar')] == ['mast_joint', 'lidar_joint']
    mast, lidar = Mount3D(0.2, 0.1, 0.3, 0.0, 0.0, math.pi / 2), Mount3D(0.05, 0.0, 0.4, math.pi, 0.2, 0.0)
    assert_same_mount(mount_of(joints, 'base_link', 'lidar'), Mount3D.from_matrix(mast.matrix() @ lidar.matrix()))
    composed = mount_of(joints, 'base_link', 'lidar')
    # the lidar's x axis, pitched down 0.2 rad on a mast turned 90 deg: along the base's y, a little down
    ahead = composed.apply(np.array([[1.0, 0.0, 0.0]]))[0]
    assert ahead == pytest.approx([0.2, 0.15 + math.cos(0.2), 0.7 - math.sin(0.2)])
    assert mount_of(joints, 'base_footprint', 'lidar').z == pytest.approx(composed.z + 0.1)
    with pytest.raises(UrdfError, match='no chain of fixed joints from lidar down to base_link'):
        mount_of(joints, 'lidar', 'base_link')
    with pytest.raises(UrdfError, match='from base_link down to wheel'):
        mount_of(joints, 'base_link', 'wheel')       # a moving joint is no mounting


def test_frame_only_links_are_left_out_of_the_simulated_body(tmp_path):
    """A link without <inertial> is a frame: pybullet would give it 1 kg and another link in
    the multibody, changing every seeded run; the simulator loads the bodies alone."""
    import xml.etree.ElementTree as ElementTree
    bodies = ElementTree.fromstring(bodies_only(robot.URDF))
    assert {link.get('name') for link in bodies.findall('link')} == {'base_link', 'left_wheel', 'right_wheel',
                                                                     'caster', 'laser'}
    assert {j.get('name') for j in bodies.findall('joint')} == {'left_wheel_joint', 'right_wheel_joint',
                                                               'caster_joint', 'laser_joint'}
    path = tmp_path / 'mast.urdf'
    path.write_text(MAST_URDF.replace('<link name="lidar"/>', '<link name="lidar"><inertial/></link>'))
    with pytest.raises(UrdfError, match='link lidar has a body but hangs on the frame-only link mast'):
        bodies_only(str(path))


def test_a_malformed_urdf_says_where(tmp_path):
    path = tmp_path / 'bad.urdf'
    path.write_text(MAST_URDF.replace('xyz="0.05 0 0.4"', 'xyz="0.05 0"'))
    with pytest.raises(UrdfError, match='fixed joint lidar_joint: <origin> needs xyz and rpy'):
        fixed_joints(str(path))
    path.write_text('<robot><joint')
    with pytest.raises(UrdfError, match='bad.urdf'):
        fixed_joints(str(path))
