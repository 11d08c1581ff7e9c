"""Reading recorded and live messages without ROS: rclpy's messages and rosbags' carry the
same field names, so one reader serves the server and the offline commands."""
