"""The simulated robot without ROS: the pybullet Pioneer 3-DX simulator, the laser it
carries (and, optionally, a rear laser and a 16-ring 3D lidar in a world
extruded in 3D), and physics-free synthetic scans (ray caster, random free poses, local maps cut
from the map). Its ROS node is global_loc.ros.sim_node."""
