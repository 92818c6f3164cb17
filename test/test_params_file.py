"""config/online_em_slam.yaml is generated from the parameter specs (issue 10 item 3: one source)."""
from pathlib import Path

import pytest
import yaml

from online_em_slam.ros.params import all_specs
from online_em_slam.ros.params_file import generate

CONFIG = Path(__file__).resolve().parents[1] / "config" / "online_em_slam.yaml"


def test_the_committed_parameter_file_is_the_generated_one():
    assert CONFIG.read_text() == generate(), (
        "config/online_em_slam.yaml is stale: python -m online_em_slam.ros.params_file > config/online_em_slam.yaml")


def test_every_spec_appears_once_with_its_default():
    values = yaml.safe_load(generate())["/**"]["ros__parameters"]
    specs = {spec.name: spec for spec in all_specs()}
    assert set(values) == set(specs)
    for name, spec in specs.items():
        default = list(spec.default) if isinstance(spec.default, tuple) else spec.default
        numeric = isinstance(default, float) or (isinstance(default, list) and default
                                                 and all(isinstance(v, float) for v in default))
        assert values[name] == (pytest.approx(default, rel=1e-9) if numeric else default), name
