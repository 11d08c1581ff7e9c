#!/usr/bin/env python3
"""The main job: the pybullet simulator puts a Pioneer 3-DX at a random free pose of the
shipped office map (the kidnapping), the global_loc server localizes it from one scan
when the client asks, and this script prints the estimated and the true pose with the
error, and saves a picture. Three real processes over DDS on a private domain.

usage: demo.py [SEED] [METHOD]
"""
import os
import random
import sys
import tempfile

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from sensor_msgs.msg import LaserScan

from global_loc.core.map_io import load_map_yaml
from global_loc.core.paths import default_map_yaml
from global_loc.core.scan import scan_to_points
from global_loc.core.transform import CORRECT_XY_M, CORRECT_YAW_DEG, format_pose, pose_correct, pose_error
from global_loc.offline.plot import DrawnPoses, plot_localization
from global_loc.ros.convert import pose_from_msg, scan_from_msg
from global_loc.sim.raycast import sample_free_poses
from global_loc.sim.simulator import BASE_T_LASER
from global_loc.testing.processes import TopicRecorder, isolated_env, reliable, start_client, start_server, start_sim


def main():
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else random.randrange(1_000_000)
    method = sys.argv[2] if len(sys.argv) > 2 else ''
    map_yaml = default_map_yaml()
    occupancy_map = load_map_yaml(map_yaml)
    start = sample_free_poses(occupancy_map, 1, np.random.default_rng(seed))[0]
    out_dir = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'out')
    os.makedirs(out_dir, exist_ok=True)
    logs = tempfile.mkdtemp(prefix='global_loc_demo_')
    env = isolated_env()
    print(f'kidnapping the robot to a random free pose of {os.path.basename(map_yaml)} (seed {seed})')
    sim = start_sim(env, os.path.join(logs, 'sim.log'), f'x:={start.x}', f'y:={start.y}', f'yaw:={start.yaw}',
                    f'seed:={seed}')
    server = start_server(env, os.path.join(logs, 'server.log'), f'laser_x:={BASE_T_LASER.x}',
                          f'laser_y:={BASE_T_LASER.y}', f'laser_yaw:={BASE_T_LASER.yaw}')
    recorder = TopicRecorder(env, {'/initialpose': (PoseWithCovarianceStamped, reliable()),
                                   '/sim/true_pose': (PoseStamped, reliable(latched=True)),
                                   '/scan': (LaserScan, 5)})
    code = 1
    try:
        recorder.wait_for_publisher('/initialpose')
        print('asking the server (ros2 run global_loc test_global_loc) ...', flush=True)
        code = start_client(env, '--timeout', '10', *(['--method', method] if method else [])).wait()
        truths = recorder.wait_for('/sim/true_pose', 1)
        truth = pose_from_msg(truths[-1].pose)
        published = recorder.wait_for('/initialpose', 1, timeout=3.0 if code == 0 else 0.5)
        print()
        print(f'true pose:      {format_pose(truth)}')
        estimate = None
        if published:
            estimate = pose_from_msg(published[-1].pose.pose)
            d, a = pose_error(estimate, truth)
            print(f'estimated pose: {format_pose(estimate)}   (from /initialpose)')
            verdict = 'right' if pose_correct(estimate, truth) else 'WRONG'
            print(f'error:          {d:.3f} m, {a:.1f} deg  ->  {verdict} '
                  f'(thesis criterion: < {CORRECT_XY_M} m and < {CORRECT_YAW_DEG:g} deg)')
        else:
            print('estimated pose: none published (see the client output above)')
        scans = recorder.messages['/scan']
        if scans:
            path = os.path.join(out_dir, 'demo.png')
            plot_localization(path, occupancy_map, scan_to_points(scan_from_msg(scans[-1])).points,
                              DrawnPoses(estimate, truth), BASE_T_LASER, title=f'global_loc demo, seed {seed}')
            print(f'picture:        {path}')
        print(f'logs:           {logs}')
    finally:
        recorder.close()
        server.stop()
        sim.stop()
    return code


if __name__ == '__main__':
    sys.exit(main())
