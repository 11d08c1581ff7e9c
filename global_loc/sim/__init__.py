"""The simulated robot without ROS: the pybullet Pioneer 3-DX simulator, the laser it
carries, and physics-free synthetic scans (ray caster, random free poses, local maps cut
from the map). Its ROS node is global_loc.ros.sim_node."""
