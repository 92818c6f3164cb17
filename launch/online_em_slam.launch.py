"""Launch the online EM SLAM node with its parameter file, optionally RViz and a bag.

    ros2 launch online_em_slam online_em_slam.launch.py
    ros2 launch online_em_slam online_em_slam.launch.py use_sim_time:=true \
        params_file:=/path/to/my.yaml namespace:=robot1
    # A managed node: nav2's lifecycle manager configures and activates it (autostart), or
    # nothing does until `ros2 lifecycle set /online_em_slam configure` (autostart:=false).
    ros2 launch online_em_slam online_em_slam.launch.py use_lifecycle_manager:=true
    # A converted KTH bag (online-em-slam-convert car_park car_park_bag), RViz and the node
    # on sim time: `ros2 bag play --clock` starts after bag_delay seconds.
    ros2 launch online_em_slam online_em_slam.launch.py rviz:=true bag:=$PWD/car_park_bag \
        params_file:=$(ros2 pkg prefix online_em_slam)/share/online_em_slam/config/car_park.yaml

With ``bag`` set, ``use_sim_time`` is forced on for the node and RViz (the bag's
/clock drives them).  Under a ``namespace`` RViz runs in it with the config's robot
topics moved there (``online_em_slam.ros.rviz_config``); ``namespaced_tf:=true`` puts
/tf and /tf_static in the namespace too (each robot its own TF tree, the nav2
multi-robot recipe; see multi_robot.launch.py).  RViz and ``ros2 bag play`` need a real Jazzy install (rviz2,
rosbag2); in the PyPI-wheels set-up use ``online-em-slam-replay BAG --clock`` and
``python -m online_em_slam.ros.node`` instead (README).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess, OpaqueFunction, TimerAction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def _arguments(share):
    return [
        DeclareLaunchArgument("use_sim_time", default_value="false",
                              description="Use the /clock topic (bag replay, simulation)."),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "online_em_slam.yaml"),
                              description="Parameter YAML (/** + ros__parameters)."),
        DeclareLaunchArgument("namespace", default_value="", description="Node namespace (RViz follows it)."),
        DeclareLaunchArgument("namespaced_tf", default_value="false",
                              description="Remap /tf and /tf_static into the namespace (one TF tree per robot)."),
        DeclareLaunchArgument("autostart", default_value="true",
                              description="Configure and activate the lifecycle node at start."),
        DeclareLaunchArgument("use_lifecycle_manager", default_value="false",
                              description="nav2_lifecycle_manager drives the node (with autostart) instead "
                                          "of the node itself."),
        DeclareLaunchArgument("use_respawn", default_value="false",
                              description="Restart the node if it exits (2 s later)."),
        DeclareLaunchArgument("log_level", default_value="info", description="Logging level."),
        DeclareLaunchArgument("rviz", default_value="false", description="Start RViz with rviz_config."),
        DeclareLaunchArgument("rviz_config", default_value=os.path.join(share, "rviz", "online_em_slam.rviz"),
                              description="RViz configuration (its robot topics are moved into the namespace)."),
        DeclareLaunchArgument("rviz_fixed_frame", default_value="",
                              description="RViz fixed frame (empty: the config's, map)."),
        DeclareLaunchArgument("bag", default_value="",
                              description="Bag to play with `ros2 bag play --clock` (empty: none)."),
        DeclareLaunchArgument("bag_rate", default_value="1.0", description="Playback rate of the bag."),
        DeclareLaunchArgument("bag_delay", default_value="3.0",
                              description="Seconds before the bag starts (node and RViz subscribe first)."),
    ]


def _tf_remappings():
    """/tf and /tf_static into the namespace with namespaced_tf (else a no-op remap)."""
    inside = PythonExpression(["'", LaunchConfiguration("namespaced_tf"), "'.lower() == 'true'"])
    return [(topic, PythonExpression(["'", topic.lstrip("/"), "' if ", inside, " else '", topic, "'"]))
            for topic in ("/tf", "/tf_static")]


def _rviz(context, sim_time):
    """RViz in the node's namespace, with the config's robot topics moved there."""
    from online_em_slam.ros.rviz_config import write_namespaced_config
    namespace = LaunchConfiguration("namespace").perform(context)
    config = write_namespaced_config(LaunchConfiguration("rviz_config").perform(context), namespace,
                                     LaunchConfiguration("rviz_fixed_frame").perform(context))
    return [Node(package="rviz2", executable="rviz2", name="rviz2", namespace=namespace, output="log",
                 arguments=["-d", config], parameters=[{"use_sim_time": sim_time}],
                 remappings=_tf_remappings())]


def generate_launch_description():
    share = get_package_share_directory("online_em_slam")
    bag = LaunchConfiguration("bag")
    has_bag = PythonExpression(["'", bag, "' != ''"])
    # A bag brings its own clock: sim time on whenever one is played.
    sim_time = ParameterValue(
        PythonExpression(["'", LaunchConfiguration("use_sim_time"), "'.lower() == 'true' or ", has_bag]),
        value_type=bool)
    autostart, managed = LaunchConfiguration("autostart"), LaunchConfiguration("use_lifecycle_manager")
    # The node starts itself only when no lifecycle manager is asked to.
    self_start = ParameterValue(
        PythonExpression(["'", autostart, "'.lower() == 'true' and '", managed, "'.lower() != 'true'"]),
        value_type=bool)
    slam = Node(
        package="online_em_slam", executable="online_em_slam_node", name="online_em_slam",
        namespace=LaunchConfiguration("namespace"), output="screen", emulate_tty=True,
        parameters=[LaunchConfiguration("params_file"), {"use_sim_time": sim_time, "autostart": self_start}],
        remappings=_tf_remappings(),
        respawn=PythonExpression(["'", LaunchConfiguration("use_respawn"), "'.lower() == 'true'"]), respawn_delay=2.0,
        arguments=["--ros-args", "--log-level", LaunchConfiguration("log_level")])
    manager = Node(
        package="nav2_lifecycle_manager", executable="lifecycle_manager", name="lifecycle_manager_slam",
        namespace=LaunchConfiguration("namespace"), output="screen",
        parameters=[{"use_sim_time": sim_time, "node_names": ["online_em_slam"],
                     "autostart": ParameterValue(PythonExpression(["'", autostart, "'.lower() == 'true'"]),
                                                 value_type=bool)}],
        condition=IfCondition(managed))
    rviz = OpaqueFunction(function=_rviz, kwargs={"sim_time": sim_time},
                          condition=IfCondition(LaunchConfiguration("rviz")))
    play = TimerAction(period=LaunchConfiguration("bag_delay"), actions=[ExecuteProcess(
        cmd=["ros2", "bag", "play", bag, "--clock", "--rate", LaunchConfiguration("bag_rate")],
        output="screen", condition=IfCondition(has_bag))])
    return LaunchDescription(_arguments(share) + [slam, manager, rviz, play])
