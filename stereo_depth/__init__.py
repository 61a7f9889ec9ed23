"""stereo_depth: depth from a calibrated stereo camera, live on ROS 2 topics or offline on rosbag2 files."""

__version__ = "0.1.0"
