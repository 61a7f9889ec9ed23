"""ament_python package: `colcon build` installs the nodes to lib/stereo_depth for `ros2 run`."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "stereo_depth"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*")),
        # sourced by `source install/setup.bash` (colcon.pkg lists them): the large-message profile for
        # every process of that shell, only when none is set (README "Inputs and outputs over DDS")
        (f"share/{PACKAGE}/environment", glob("environment/*")),
    ],
    install_requires=["setuptools"],
    extras_require={"ray": ["ray>=2.60"]},  # `process --ray`: bags as tasks on a Ray cluster
    zip_safe=True,
    maintainer="stereo_depth maintainers",
    maintainer_email="maintainers@stereo-depth.invalid",
    description="Depth from a calibrated stereo camera, live on ROS 2 topics and offline on rosbag2 files",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "stereo-depth = stereo_depth.cli:main",
            "stereo_node = stereo_depth.nodes.entry_points:stereo_node",
            "stereo_lifecycle_node = stereo_depth.nodes.entry_points:stereo_lifecycle_node",
            "disparity_node = stereo_depth.nodes.entry_points:disparity_node",
            "point_cloud_node = stereo_depth.nodes.entry_points:point_cloud_node",
            "rectify_node = stereo_depth.nodes.entry_points:rectify_node",
        ],
    },
)
