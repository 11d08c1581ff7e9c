"""The ROS-free core: pose and grid geometry, map loading, scans, local maps, the
matchers and the Localizer pipeline, typed outcomes. Imports numpy, OpenCV, scipy and
numba, never rclpy or a message package (test_core_without_ros.py checks it)."""
