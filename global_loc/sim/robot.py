"""The simulated Pioneer 3-DX as pioneer3dx.urdf describes it: the frames the simulator
stamps its sensors' messages with, and where each sensor sits on base_link, read from the
URDF's fixed joints. One source for both uses: the simulator casts its rays from these
mountings (sim/simulator.py) and its node publishes the same joints on /tf_static
(ros/sim_node.py), so what the server is told is what the rays did."""
from __future__ import annotations

import os

from ..io.urdf import fixed_joints, mount_of

URDF = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'pioneer3dx.urdf')
BASE_FRAME = 'base_link'
LASER_FRAME = 'laser'                # /scan
REAR_LASER_FRAME = 'laser_rear'      # /scan_rear (rear_laser)
LIDAR_FRAME = 'lidar'                # /points (lidar3d)

JOINTS = fixed_joints(URDF)          # child link -> its fixed joint
FRONT_LASER_MOUNT = mount_of(JOINTS, BASE_FRAME, LASER_FRAME)
REAR_LASER_MOUNT = mount_of(JOINTS, BASE_FRAME, REAR_LASER_FRAME)
LIDAR_MOUNT = mount_of(JOINTS, BASE_FRAME, LIDAR_FRAME)
