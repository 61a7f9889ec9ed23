"""rosbag2 files without a ROS install: read stereo frames, write results, make bags, replay them.

Imports rosbags, never rclpy (only `replay` needs it, imported inside its functions).
"""
