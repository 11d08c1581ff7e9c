"""The command line without ROS (`python -m global_loc localize | simulate`): localization of
JSON lines, rosbag2 recordings and CARMEN logs, one sensor or several merged, replayed with
resolution by motion, and drawn on the map."""
