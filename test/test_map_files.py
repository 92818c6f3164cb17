"""Issue 23 item 8: ~/save_map and ~/load_map take a file name per call
(rcl_interfaces/srv/SetParameters, one string argument ``file``), resolved inside the map
directory; bad names and bad arguments are refused with a one-line reason."""
import os

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from online_em_slam.ros.map_files import MapArgumentError, requested_file, with_suffix  # noqa: E402


def argument(name="file", value="run1", kind=ParameterType.PARAMETER_STRING) -> Parameter:
    v = ParameterValue(type=kind)
    if kind == ParameterType.PARAMETER_STRING:
        v.string_value = value
    elif kind == ParameterType.PARAMETER_INTEGER:
        v.integer_value = int(value)
    return Parameter(name=name, value=v)


def request(*arguments) -> SetParameters.Request:
    return SetParameters.Request(parameters=list(arguments))


# ----------------------------------------------------------------- the request, without a node
def test_requested_file_reads_one_string_argument_named_file():
    assert requested_file([]) is None                      # no argument: the map_file parameter
    assert requested_file([argument(value="maps/run1.npz")]) == "maps/run1.npz"


@pytest.mark.parametrize("arguments, expected", [
    ([argument(name="filename")], "unknown argument 'filename'"),
    ([argument(kind=ParameterType.PARAMETER_INTEGER, value=3)], "must be a string"),
    ([argument(), argument(value="b")], "one argument expected, got 2")])
def test_requested_file_refuses_other_arguments(arguments, expected):
    with pytest.raises(MapArgumentError, match=expected) as error:
        requested_file(arguments)
    assert "\n" not in str(error.value) and "'file'" in str(error.value)


def test_names_without_the_suffix_get_it():
    assert with_suffix("run1") == "run1.npz"
    assert with_suffix(" run1.npz ") == "run1.npz"
    assert with_suffix("sub/run1") == "sub/run1.npz"
    assert with_suffix("") == ""


# ----------------------------------------------------------------- live node
def test_save_under_a_name_load_it_back_and_refuse_bad_names(ros, tmp_path):
    from test_node import T0
    from test_reliability_node import drive
    maps, outside = tmp_path / "maps", tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.npz").write_bytes(b"precious")
    node = ros.start(motion_source="odom", map_directory=str(maps), map_file="default.npz")
    drive(ros, node, T0, 10)
    assert len(node.slam.landmarks()) == 2

    # Save under a name (".npz" added), inside the map directory; a subdirectory is created.
    for name, path in (("run1", maps / "run1.npz"), ("site/run2.npz", maps / "site" / "run2.npz")):
        result = ros.call(SetParameters, "save_map", request(argument(value=name))).results
        assert len(result) == 1 and result[0].successful, result[0].reason
        assert str(path) in result[0].reason and path.exists()
    assert not (maps / "default.npz").exists()

    # Load it back after a reset: the same landmarks.
    assert ros.call(Trigger, "reset", Trigger.Request()).success
    assert len(node.slam.landmarks()) == 0
    result = ros.call(SetParameters, "load_map", request(argument(value="run1"))).results[0]
    assert result.successful and str(maps / "run1.npz") in result.reason, result.reason
    with np.load(maps / "run1.npz") as data:
        saved_positions = np.array(data["theta"])
    assert len(saved_positions) == 2
    np.testing.assert_allclose(node.slam.landmarks().positions, saved_positions)

    # No argument: the map_file parameter, as the Trigger services.
    result = ros.call(SetParameters, "save_map", request()).results[0]
    assert result.successful and (maps / "default.npz").exists(), result.reason
    assert ros.call(Trigger, "load_map_file", Trigger.Request()).success

    # Bad names and bad arguments: refused with the reason, nothing written or read outside.
    bad = {"../outside/victim": "'..' is not allowed",
           str(outside / "victim.npz"): "outside the map directory",
           "/etc/passwd": "outside the map directory",
           "": "map file name is empty",
           "missing": "missing.npz"}
    for service in ("save_map", "load_map"):
        for name, expected in bad.items():
            if service == "save_map" and name == "missing":
                continue
            result = ros.call(SetParameters, service, request(argument(value=name))).results[0]
            verb = service.split("_")[0]
            assert not result.successful and result.reason.startswith(f"could not {verb} map:"), result.reason
            assert expected in result.reason and "\n" not in result.reason, (name, result.reason)
        result = ros.call(SetParameters, service, request(argument(name="name"))).results[0]
        assert not result.successful and "unknown argument 'name'" in result.reason
    assert os.listdir(outside) == ["victim.npz"] and (outside / "victim.npz").read_bytes() == b"precious"
    # The estimate is what was loaded: a refused load leaves it as it was.
    np.testing.assert_allclose(node.slam.landmarks().positions, saved_positions)
