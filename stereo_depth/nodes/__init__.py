"""The ROS nodes, one console script each (`ros2 run stereo_depth <name>`; stereo_lifecycle_node is
managed), in `entry_points.py`, which installs the signal handlers before it imports the node's module;
each node's `main` is `ros.node_main.run_node`. Run as `python -m stereo_depth.nodes.<name>`, a node
gets its handlers here, before its module's imports: Python imports this package first, while
`sys.argv[0]` is still "-m". Importing a node otherwise installs no handler.
"""

import sys

if sys.argv[:1] == ["-m"]:
    from stereo_depth.ros import signals

    signals.install()
