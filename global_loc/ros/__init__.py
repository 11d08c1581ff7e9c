"""The ROS 2 side: the action server, its parameters, the client, the simulator node,
message conversion and the node runner. Everything here translates messages and calls
global_loc.core."""
