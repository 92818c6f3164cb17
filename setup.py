"""ament_python package setup for online_em_slam (colcon build / pip install)."""
import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "online_em_slam"


def tree(source, target_root):
    """data_files entries installing every file below ``source`` keeping its layout."""
    entries = {}
    for path in glob(os.path.join(source, "**", "*"), recursive=True):
        if os.path.isfile(path):
            target = os.path.join(target_root, os.path.dirname(path))
            entries.setdefault(target, []).append(path)
    return sorted(entries.items())


def tf2_msgs_build_requirements():
    """The pip requirements of the first-use tf2_msgs build (package data, read by it too)."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), PACKAGE, "messages", "tf2_build", "source",
                        "requirements.txt")
    with open(path) as handle:
        lines = (line.split("#", 1)[0].strip() for line in handle)
        return [line for line in lines if line]


share = os.path.join("share", PACKAGE)

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    # The tf2_msgs (TFMessage only) sources and build requirements, so that an installed
    # package builds tf2_msgs on first use where it is not on PyPI (online_em_slam.messages.tf2_build).
    package_data={f"{PACKAGE}.messages.tf2_build": ["source/package.xml", "source/CMakeLists.txt",
                                                    "source/msg/TFMessage.msg", "source/requirements.txt"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [os.path.join("resource", PACKAGE)]),
        (share, ["package.xml"]),
        (os.path.join(share, "launch"), glob("launch/*.py")),
        (os.path.join(share, "config"), glob("config/*.yaml")),
        (os.path.join(share, "config", "hand_tuned"), glob("config/hand_tuned/*.yaml")),
        (os.path.join(share, "rviz"), glob("rviz/*.rviz")),
    ] + tree(os.path.join("data", "kth"), share),
    # The core, the bag tools and the plots; ROS itself comes from apt on a real Jazzy
    # install (package.xml), or from the PyPI wheels with the "ros" extra, which also brings
    # what building tf2_msgs (not on PyPI) on first use needs: rosidl, ament_cmake, cmake, ninja.
    install_requires=["setuptools", "numpy>=1.24", "scipy>=1.10", "pyyaml>=6", "rosbags>=0.10",
                      "matplotlib>=3.7"],
    zip_safe=False,                  # the tf2_msgs sources are read from the installed files
    maintainer="online_em_slam maintainers",
    maintainer_email="maintainer@example.com",
    description="Landmark SLAM by particle online EM (ROS 2 node and ROS-free core)",
    license="Apache-2.0",
    extras_require={
        "ros": ["ros-jazzy-rclpy[fastrtps]", "ros-jazzy-nav-msgs", "ros-jazzy-geometry-msgs",
                "ros-jazzy-sensor-msgs", "ros-jazzy-visualization-msgs", "ros-jazzy-diagnostic-msgs",
                "ros-jazzy-std-srvs", "ros-jazzy-rosgraph-msgs"] + tf2_msgs_build_requirements(),
        "benchmark": ["gtsam>=4.2"],
        "test": ["pytest>=7", "pytest-xdist>=3", "wheel"],
    },
    entry_points={
        "console_scripts": [
            "online_em_slam_node = online_em_slam.ros.node:main",
            "online-em-slam = online_em_slam.offline.cli:main",
            "online-em-slam-convert = online_em_slam.datasets.convert:main",
            "online-em-slam-replay = online_em_slam.bag.replay:main",
            "beacon_extractor_node = online_em_slam.datasets.kth.beacon_node:main",
            "online-em-slam-benchmark = online_em_slam.experiments.benchmark:main",
            "online-em-slam-record = online_em_slam.bag.record:main",
            "online-em-slam-topic = online_em_slam.bag.topic_tool:main",
            "online-em-slam-demo = online_em_slam.experiments.demo:main",
            "online-em-slam-mrclam-benchmark = online_em_slam.datasets.mrclam.benchmark:main",
            "online-em-slam-tf2-msgs = online_em_slam.messages.tf2_build.cli:main",
        ],
    },
)
