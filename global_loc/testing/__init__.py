"""Harnesses for the tests, the demo and the benchmark's real-process suites: starting the
nodes as processes on a private DDS domain (no ros2 launch on PyPI) and the benchmark's
ROS side. Not used by the server, the client or the offline commands."""
