"""One online EM SLAM node for a fleet: several robots, one map (docs/NODE.md, "Fleet mode").

    ros2 launch online_em_slam fleet.launch.py robots:=robot1,robot2 \
        params_file:=/path/to/fleet.yaml rviz:=true use_sim_time:=true

``robots`` (comma-separated namespaces) becomes the node's ``robots`` parameter: the node
reads ``/robotK/odom`` (or ``control``), ``/robotK/landmark_observations`` and
``/robotK/initialpose``, publishes ``/robotK/pose``, ``path``, ``particles`` and map ->
``robotK/odom`` on the shared /tf (nav2's multi-robot frame names), and one map on
``~/landmarks``.  Each robot's start (``initial_poses``, 3 numbers per robot) belongs in
the parameter file.  ``rviz:=true`` starts one RViz with every robot's displays
(``online_em_slam.ros.rviz_config.fleet_config``).  ``local_robot:=robot1`` starts the
distributed mode's node for that robot (node ``online_em_slam_robot1``): it drives robot1 only
and shares the map with the other robots' nodes, each launched the same way on its robot
(docs/NODE.md, "Distributed").  For one independent node (and map) per robot use
multi_robot.launch.py.  Needs a real Jazzy install (launch, rviz2); in the
PyPI-wheels set-up run ``python -m online_em_slam.ros.node --ros-args -p robots:=[...]``.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def _arguments(share):
    return [
        DeclareLaunchArgument("robots", default_value="robot1,robot2",
                              description="The robots' namespaces, comma-separated."),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "online_em_slam.yaml"),
                              description="Parameter YAML (/** + ros__parameters), with initial_poses."),
        DeclareLaunchArgument("local_robot", default_value="",
                              description="Distributed mode: the one robot this node drives (empty: all)."),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="Use /clock."),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="Configure and activate the lifecycle node at start."),
        DeclareLaunchArgument("log_level", default_value="info", description="Logging level."),
        DeclareLaunchArgument("rviz", default_value="false", description="Start RViz with every robot's displays."),
        DeclareLaunchArgument("rviz_config", default_value=os.path.join(share, "rviz", "online_em_slam.rviz"),
                              description="RViz configuration whose robot displays are repeated per robot."),
    ]


def _robots(context) -> list[str]:
    return [r.strip() for r in LaunchConfiguration("robots").perform(context).split(",") if r.strip()]


def _slam(context, sim_time):
    local = LaunchConfiguration("local_robot").perform(context).strip()
    return [Node(
        package="online_em_slam", executable="online_em_slam_node",
        name=f"online_em_slam_{local.replace('/', '_')}" if local else "online_em_slam", output="screen",
        emulate_tty=True,
        parameters=[LaunchConfiguration("params_file"),
                    {"use_sim_time": sim_time, "robots": _robots(context), "local_robot": local,
                     "autostart": ParameterValue(PythonExpression(["'", LaunchConfiguration("autostart"),
                                                                   "'.lower() == 'true'"]), value_type=bool)}],
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")])]


def _rviz(context, sim_time):
    """RViz with the config's robot displays once per robot (rviz_config.fleet_config)."""
    import tempfile

    from online_em_slam.ros.rviz_config import fleet_config
    with open(LaunchConfiguration("rviz_config").perform(context), encoding="utf-8") as handle:
        text = fleet_config(handle.read(), _robots(context))
    with tempfile.NamedTemporaryFile("w", prefix="online_em_slam_fleet_", suffix=".rviz", delete=False) as out:
        out.write(text)
    return [Node(package="rviz2", executable="rviz2", name="rviz2", output="log", arguments=["-d", out.name],
                 parameters=[{"use_sim_time": sim_time}])]


def generate_launch_description():
    share = get_package_share_directory("online_em_slam")
    sim_time = ParameterValue(PythonExpression(["'", LaunchConfiguration("use_sim_time"), "'.lower() == 'true'"]),
                              value_type=bool)
    slam = OpaqueFunction(function=_slam, kwargs={"sim_time": sim_time})
    rviz = OpaqueFunction(function=_rviz, kwargs={"sim_time": sim_time},
                          condition=IfCondition(LaunchConfiguration("rviz")))
    return LaunchDescription(_arguments(share) + [slam, rviz])
