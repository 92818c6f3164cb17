"""Launch the online EM SLAM node with its parameter file.

    ros2 launch online_em_slam online_em_slam.launch.py
    ros2 launch online_em_slam online_em_slam.launch.py use_sim_time:=true \
        params_file:=/path/to/my.yaml namespace:=robot1
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("online_em_slam"), "config",
                                  "online_em_slam.yaml")
    use_sim_time = LaunchConfiguration("use_sim_time")
    params_file = LaunchConfiguration("params_file")
    namespace = LaunchConfiguration("namespace")
    log_level = LaunchConfiguration("log_level")

    return LaunchDescription([
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="Use the /clock topic (bag replay, simulation)."),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="Parameter YAML (/** + ros__parameters)."),
        DeclareLaunchArgument("namespace", default_value="", description="Node namespace."),
        DeclareLaunchArgument("log_level", default_value="info", description="Logging level."),
        Node(
            package="online_em_slam",
            executable="online_em_slam_node",
            name="online_em_slam",
            namespace=namespace,
            output="screen",
            emulate_tty=True,
            parameters=[params_file, {"use_sim_time": ParameterValue(use_sim_time, value_type=bool)}],
            arguments=["--ros-args", "--log-level", log_level],
        ),
    ])
