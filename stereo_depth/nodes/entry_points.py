"""The console scripts (`ros2 run stereo_depth <node>`): the signal handlers go in first, then the
node's module is imported (rclpy, OpenCV, numpy: a second or more on a loaded machine) and its `main`
runs, which returns 0 at once if Ctrl-C or SIGTERM came during the imports (ros/signals.py)."""

from __future__ import annotations

import importlib
from functools import partial

from stereo_depth.ros import signals


def _run(module: str) -> int:
    signals.install()
    main = importlib.import_module(f"stereo_depth.nodes.{module}").main
    code: int = main()
    return code


stereo_node = partial(_run, "stereo_node")
stereo_lifecycle_node = partial(_run, "stereo_lifecycle_node")
disparity_node = partial(_run, "disparity_node")
point_cloud_node = partial(_run, "point_cloud_node")
rectify_node = partial(_run, "rectify_node")
