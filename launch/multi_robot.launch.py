"""Two robots, each with its own online EM SLAM node, in namespaces robot1 and robot2.

    ros2 launch online_em_slam multi_robot.launch.py
    ros2 launch online_em_slam multi_robot.launch.py rviz:=true use_sim_time:=true \
        robot1_params_file:=/path/to/robot1.yaml robot2_params_file:=/path/to/robot2.yaml

Each node runs online_em_slam.launch.py under its namespace: it reads ``odom`` (or
``control``), ``landmark_observations`` and ``initialpose`` in it and publishes
``/robotN/online_em_slam/*``.  With ``namespaced_tf`` (default true here) /tf and
/tf_static are remapped into the namespace, so each robot has its own TF tree with the
usual frame names (map -> odom -> base_link on /robotN/tf), as nav2's multi-robot
bring-up does: the robot's drivers must publish there too.  With ``namespaced_tf:=false``
the robots share /tf and their params files must give them distinct frames
(``map_frame: robot1/map``, ``odom_frame``, ``base_frame``, ``sensor_frame``).
``rviz:=true`` starts one RViz per robot, each showing its own robot's topics.
The parameter files use ``/**:`` keys, which apply in any namespace.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration

ROBOTS = ("robot1", "robot2")


def _arguments(share):
    reference = os.path.join(share, "config", "online_em_slam.yaml")
    arguments = [
        DeclareLaunchArgument("use_sim_time", default_value="false", description="Use /clock."),
        DeclareLaunchArgument("namespaced_tf", default_value="true",
                              description="Each robot's /tf and /tf_static in its namespace."),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="Configure and activate the lifecycle nodes at start."),
        DeclareLaunchArgument("rviz", default_value="false", description="One RViz per robot."),
    ]
    for robot in ROBOTS:
        arguments.append(DeclareLaunchArgument(f"{robot}_params_file", default_value=reference,
                                               description=f"Parameter YAML of {robot}'s node."))
    return arguments


def _robot(share, robot):
    """online_em_slam.launch.py under ``robot``, in a scope of its own (its launch configurations
    do not leak into the other robot's)."""
    return GroupAction(scoped=True, actions=[IncludeLaunchDescription(
        PythonLaunchDescriptionSource(os.path.join(share, "launch", "online_em_slam.launch.py")),
        launch_arguments={
            "namespace": robot,
            "params_file": LaunchConfiguration(f"{robot}_params_file"),
            "use_sim_time": LaunchConfiguration("use_sim_time"),
            "namespaced_tf": LaunchConfiguration("namespaced_tf"),
            "autostart": LaunchConfiguration("autostart"),
            "rviz": LaunchConfiguration("rviz"),
        }.items())])


def generate_launch_description():
    share = get_package_share_directory("online_em_slam")
    return LaunchDescription(_arguments(share) + [_robot(share, robot) for robot in ROBOTS])
