"""One parameter behaviour for the node and the offline runner (ROS-conventions item 4): both
refuse a name that is not a parameter (naming the nearest valid one) and let through the names
ROS itself reads; both take an integer for a double."""
import os
import subprocess
import sys
from pathlib import Path

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "OFF"

import pytest  # noqa: E402

from online_em_slam.offline import cli  # noqa: E402
from ros_domain import claim  # noqa: E402
from online_em_slam.parameters.specs import ParameterError  # noqa: E402
from online_em_slam.parameters.yaml_file import config_from_params  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TYPO = "/**:\n  ros__parameters:\n    filter:\n      num_partcles: 10\n"
INTEGERS = ("/**:\n  ros__parameters:\n    use_sim_time: false\n    motion:\n      wheelbase: 3\n"
            "    filter:\n      initial_pose_std: [1, 1, 0]\n    input_delay: 2\n"
            "    qos_overrides:\n      /parameter_events:\n        publisher:\n          depth: 100\n")
HINT = "unknown parameter: filter.num_partcles (did you mean filter.num_particles?)"


def test_run_refuses_a_misspelled_key_naming_the_nearest_one(tmp_path, capsys):
    params = tmp_path / "typo.yaml"
    params.write_text(TYPO)
    code = cli.main(["run", str(tmp_path / "no_bag"), "--params", str(params), "--output", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err == f"online-em-slam: error: {params}: {HINT}"
    with pytest.raises(ParameterError, match="did you mean odom_topic"):
        config_from_params({"odom_topc": "odom"})        # a node setting too (run ignored it)


def test_the_node_refuses_a_misspelled_key_with_one_error_line_and_status_1(tmp_path):
    params = tmp_path / "typo.yaml"
    params.write_text(TYPO)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF", ROS_DOMAIN_ID=str(claim()),
               RCUTILS_COLORIZED_OUTPUT="0")
    try:
        done = subprocess.run([sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file",
                               str(params)], capture_output=True, text=True, cwd=ROOT, env=env, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("the node started with an unknown parameter instead of refusing it")
    lines = (done.stdout + done.stderr).strip().splitlines()
    assert done.returncode == 1, lines
    assert len(lines) == 1 and "[ERROR]" in lines[0] and lines[0].endswith(HINT), lines


def test_the_node_with_a_missing_params_file_says_so_without_a_traceback(tmp_path):
    """ROS-conventions item 9: rcl refuses the arguments; one line names the file, status 1."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="OFF", RCUTILS_COLORIZED_OUTPUT="0")
    done = subprocess.run([sys.executable, "-m", "online_em_slam.ros.node", "--ros-args", "--params-file",
                           str(tmp_path / "missing.yaml")], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=30)
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert "online_em_slam_node: error: " in done.stderr and "missing.yaml" in done.stderr


def test_an_integer_for_a_double_and_ros_own_keys_are_accepted_by_both(tmp_path):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context

    from online_em_slam.ros.node import OnlineEmSlamNode
    params = tmp_path / "integers.yaml"
    params.write_text(INTEGERS)
    config, settings = config_from_params(params)               # online-em-slam run's reading
    context = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(params)], context=context)
    node = None
    try:
        node = OnlineEmSlamNode(context=context)
        assert node.get_parameter("motion.wheelbase").value == 3.0
        assert node.config == config and node.settings == settings
        assert (config.motion.wheelbase, settings.input_delay) == (3.0, 2.0)
        assert config.filter.initial_pose_std == (1.0, 1.0, 0.0)
        # ros2 param set ... 1 for a double, at run time.
        from rclpy.parameter import Parameter
        assert node.set_parameters([Parameter("transform_timeout", value=1)])[0].successful
        assert node.get_parameter("transform_timeout").value == 1.0
        with pytest.raises(ParameterError, match=r"did you mean filter\.num_particles"):
            OnlineEmSlamNode(node_name="typo", context=context,
                             parameter_overrides=[Parameter("filter.num_partcles", value=10)])
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.shutdown(context=context)


@pytest.mark.parametrize("name, value, expected", [("filter.num_particles", 100.0, "expected an integer"),
                                                   ("publish_tf", 1, "expected a boolean"),
                                                   ("motion.model", 3, "expected a string")])
def test_run_refuses_the_types_the_node_refuses(name, value, expected):
    """rclpy refuses 100.0 for an integer and 1 for a boolean; the runner did not (it kept
    num_particles a float). An integer for a double is accepted by both."""
    with pytest.raises(ParameterError, match=expected):
        config_from_params({name: value})
    config, _ = config_from_params({"motion.wheelbase": 3, "filter.num_particles": 50})
    assert config.motion.wheelbase == 3.0 and config.filter.num_particles == 50
