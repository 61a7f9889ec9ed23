"""The ROS nodes, one console script each (`ros2 run stereo_depth <name>`; stereo_lifecycle_node is
managed); each `main` is `ros.stereo_io.run_node`, which installs the signal handlers (importing a node
installs none).
"""
