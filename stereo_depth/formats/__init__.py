"""File formats from outside ROS, one reader each: scene folders, EuRoC sensor.yaml, camera_info YAML,
Kalibr camchain.yaml, and `calibration_files`, which picks the right one for a path."""
