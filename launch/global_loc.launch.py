"""global_loc server with its parameters file, for a real ROS 2 install (the `launch`
packages are not on PyPI; here, `ros2 run global_loc server --ros-args --params-file
config/global_loc.yaml` does the same).

    ros2 launch global_loc global_loc.launch.py map_yaml:=/path/map.yaml use_lifecycle_manager:=true
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    share = get_package_share_directory('global_loc')
    params_file = LaunchConfiguration('params_file')
    map_yaml = LaunchConfiguration('map_yaml')
    use_sim_time = LaunchConfiguration('use_sim_time')
    autostart = LaunchConfiguration('autostart')
    use_lifecycle_manager = LaunchConfiguration('use_lifecycle_manager')
    # Under a lifecycle manager the server must wait unconfigured: its start-up asks configure,
    # which an active server refuses (success=false) and nav2 then aborts the bring-up.
    server_autostart = PythonExpression(["'", autostart, "'.lower() == 'true' and '", use_lifecycle_manager,
                                         "'.lower() != 'true'"])
    return LaunchDescription([
        DeclareLaunchArgument('params_file', default_value=os.path.join(share, 'config', 'global_loc.yaml'),
                              description='global_loc parameters file'),
        DeclareLaunchArgument('map_yaml', default_value='', description='nav2 map YAML (empty: the shipped map)'),
        DeclareLaunchArgument('use_sim_time', default_value='false', description='use /clock'),
        DeclareLaunchArgument('autostart', default_value='true',
                              description='configure and activate the server on start'),
        DeclareLaunchArgument('use_lifecycle_manager', default_value='false',
                              description="start nav2's lifecycle_manager for the server (sets autostart false)"),
        Node(package='global_loc', executable='server', name='global_loc_server', output='screen',
             parameters=[params_file, {'map_yaml': map_yaml, 'use_sim_time': use_sim_time,
                                       'autostart': server_autostart}]),
        Node(package='nav2_lifecycle_manager', executable='lifecycle_manager', name='lifecycle_manager_global_loc',
             output='screen', condition=IfCondition(use_lifecycle_manager),
             parameters=[{'use_sim_time': use_sim_time, 'autostart': True, 'node_names': ['global_loc_server']}]),
    ])
