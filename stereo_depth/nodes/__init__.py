"""The ROS nodes, one console script each (`ros2 run stereo_depth <name>`; stereo_lifecycle_node is
managed), in `entry_points.py`, which installs the signal handlers before it imports the node's module;
each node's `main` is `ros.stereo_io.run_node` (importing a node installs no handler).
"""
