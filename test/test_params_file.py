"""config/online_em_slam.yaml is generated from the parameter specs (issue 10 item 3: one source)."""
import re
from pathlib import Path

import pytest
import yaml

from online_em_slam.parameters.specs import all_specs
from online_em_slam.parameters.reference_file import generate

CONFIG = Path(__file__).resolve().parents[1] / "config" / "online_em_slam.yaml"


def test_the_committed_parameter_file_is_the_generated_one():
    assert CONFIG.read_text() == generate(), (
        "config/online_em_slam.yaml is stale: python -m online_em_slam.parameters.reference_file > config/online_em_slam.yaml")


def test_every_spec_appears_once_with_its_default():
    values = yaml.safe_load(generate())["/**"]["ros__parameters"]
    specs = {spec.name: spec for spec in all_specs()}
    assert set(values) == set(specs)
    for name, spec in specs.items():
        default = list(spec.default) if isinstance(spec.default, tuple) else spec.default
        numeric = isinstance(default, float) or (isinstance(default, list) and default
                                                 and all(isinstance(v, float) for v in default))
        assert values[name] == (pytest.approx(default, rel=1e-9) if numeric else default), name


# ------------------------------------------------------------- one source of ranges (issue 10 item 3)
def _core_fields():
    from online_em_slam.core.config import core_parameters
    return list(core_parameters())


# Settings whose value another setting of their section must allow.
COMPANIONS = {"motion.turn_per_meter": {"model": "unicycle"}}      # the unicycle's yaw rate only


def _from_dotted(name, value):
    from online_em_slam.core.config import SlamConfig
    section, key = name.split(".")
    return SlamConfig.from_dict({section: {**COMPANIONS.get(name, {}), key: value}})


def test_every_core_field_says_what_it_may_be():
    """Each field of SlamConfig carries its description and its range or choices in its metadata."""
    cross_field_only = {"noise.rho"}          # |rho| < 0.999 sigma_range sigma_bearing: code in validate
    for name, default, info in _core_fields():
        assert info.doc.strip(), name
        if isinstance(default, bool):
            continue
        if isinstance(default, str) or (isinstance(default, tuple) and isinstance(default[0], str)):
            assert info.choices and all(d in info.choices for d in ((default,) if isinstance(default, str)
                                                                    else default)), name
        elif name not in cross_field_only:
            assert info.lo is not None and info.lo <= min(default if isinstance(default, tuple) else (default,)), name
            assert info.hi is not None and max(default if isinstance(default, tuple) else (default,)) <= info.hi, name


def test_validation_applies_the_metadata_ranges_with_their_open_bounds():
    """Just outside each range, and on each open bound, the value is refused by name and range."""
    for name, default, info in _core_fields():
        if info.lo is None or isinstance(default, (bool, tuple)):
            continue
        width = info.hi - info.lo
        outside = [info.lo - max(1, 0.01 * width), info.hi + max(1, 0.01 * width)]
        outside += [info.lo] if info.lo_open else []
        outside += [info.hi] if info.hi_open else []
        for value in outside:
            value = type(default)(value) if isinstance(default, int) else float(value)
            with pytest.raises(ValueError, match=re.escape(f"{name} = {value!r} is outside the allowed range")):
                _from_dotted(name, value)
        if not info.lo_open:
            _from_dotted(name, type(default)(info.lo))           # a closed bound is allowed


def test_rho_outside_its_bound_names_the_noise_values_that_set_it():
    """A camera's sigma_range 0.15 and sigma_bearing 0.05 put the default rho (0.01) outside
    0.999 sigma_range sigma_bearing; the message said only "noise.rho = 0.01 is outside the
    allowed range", a value the user never set."""
    from online_em_slam.core.config import SlamConfig
    with pytest.raises(ValueError, match=re.escape("noise.rho = 0.01 is outside the allowed range")) as error:
        SlamConfig.from_dict({"noise": {"sigma_range": 0.15, "sigma_bearing": 0.05}})
    assert "0.999 noise.sigma_range noise.sigma_bearing (0.15 x 0.05); set noise.rho with them" in str(error.value)
    for rho in (float("nan"), float("inf")):
        with pytest.raises(ValueError, match="noise.rho"):
            SlamConfig.from_dict({"noise": {"rho": rho}})
    SlamConfig.from_dict({"noise": {"sigma_range": 0.15, "sigma_bearing": 0.05, "rho": 0.0}})


def test_list_entries_are_checked_against_the_metadata_range():
    for name, default, info in _core_fields():
        if not isinstance(default, tuple) or info.lo is None:
            continue
        bad = list(default)
        bad[0] = info.hi + 1.0
        with pytest.raises(ValueError, match=re.escape(name)):
            _from_dotted(name, bad)


def test_ros_specs_and_descriptors_come_from_the_metadata():
    from online_em_slam.parameters.specs import constraint_text, core_specs, descriptor
    infos = {name: info for name, _, info in _core_fields()}
    specs = core_specs()
    assert [spec.name for spec in specs] == list(infos)
    for spec in specs:
        info = infos[spec.name]
        assert spec.description == info.doc or spec.name in ("motion.model", "filter.seed")
        assert spec.high == info.hi and spec.high_open == info.hi_open and spec.low_open == info.lo_open
        assert spec.low == info.lo or (spec.name == "filter.seed" and spec.low == -1)
        d = descriptor(spec)
        assert d.description == spec.description and d.additional_constraints == (constraint_text(spec) or "")
        if isinstance(spec.default, float) and spec.low is not None:
            assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (spec.low, spec.high)
        if type(spec.default) is int and spec.low is not None:
            assert (d.integer_range[0].from_value, d.integer_range[0].to_value) == (spec.low, spec.high)
    by_name = {spec.name: spec for spec in specs}
    assert constraint_text(by_name["noise.sigma_range"]) == "in (0, 100]"
    assert constraint_text(by_name["filter.initial_pose_std"]) == "each entry in [0, 1000]"


def test_every_node_setting_is_read_from_a_declared_parameter():
    """NodeSettings is built from the node specs by name (parameters/specs.py SETTING_PARAMETERS for the others)."""
    from dataclasses import fields

    from online_em_slam.parameters.specs import SETTING_PARAMETERS, NODE_SPECS, NodeSettings, build
    names = {spec.name for spec in NODE_SPECS}
    for f in fields(NodeSettings):
        source = SETTING_PARAMETERS.get(f.name, f.name)
        assert set(source if isinstance(source, tuple) else (source,)) <= names, f.name
    _, settings = build({"input_qos.depth": 7, "initial_pose.yaw": 0.5, "sensor_frame": "laser"})
    assert (settings.input_depth, settings.initial_pose, settings.sensor_frame) == (7, (0.0, 0.0, 0.5), "laser")
