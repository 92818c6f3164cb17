"""Issue 12 (reliability), pure-Python parts: parameters that used to crash the
node at the next reset (defect 3), map paths (defect 8), path publishing cost
(defect 9), odometry quaternions (defect 10) and the decoding of observation
clouds (ids, range types, zero ranges, huge bearings).  Live-node checks are in
test_reliability_node.py."""
import math

import numpy as np
import pytest

from online_em_slam.core.config import AssociationConfig, FilterConfig, ObservationNoiseConfig, SlamConfig
from online_em_slam.core.slam import OnlineEMSlam
from online_em_slam.ros.params import ParameterError, build


# ----------------------------------------------------------------- defect 3: parameters
@pytest.mark.parametrize("std", [(1.0, 1.0), (1.0,), (1.0, 1.0, 1.0, 1.0), ()])
def test_initial_pose_std_needs_exactly_three_entries(std):
    with pytest.raises(ValueError, match=r"filter\.initial_pose_std .*exactly 3"):
        FilterConfig(initial_pose_std=std).validate()


def test_initial_pose_std_scalar_is_refused_not_broadcast():
    with pytest.raises(ValueError, match=r"filter\.initial_pose_std"):
        FilterConfig(initial_pose_std=1.0).validate()


@pytest.mark.parametrize("field, value", [
    ("mixture_weights", (math.nan, 1.0)), ("mixture_weights", (0.5, math.nan)),
    ("mixture_weights", (math.inf, 0.0)), ("mixture_scales", (1.0, math.nan)),
    ("mixture_scales", (math.inf, 5.0)), ("mixture_scales", (1.0, -5.0))])
def test_non_finite_mixture_entries_are_refused(field, value):
    with pytest.raises(ValueError, match=rf"noise\.{field}"):
        ObservationNoiseConfig(model="mixture", **{field: value}).validate()


def test_gate_probability_one_names_gate_probability():
    with pytest.raises(ValueError, match=r"association\.gate_probability = 1\.0") as error:
        AssociationConfig(gate_probability=1.0).validate()
    assert "new_landmark_probability" not in str(error.value)
    with pytest.raises(ValueError, match=r"association\.new_landmark_probability = 1\.0"):
        AssociationConfig(new_landmark_probability=1.0).validate()


@pytest.mark.parametrize("name, value", [
    ("filter.initial_pose_std", [1.0, 1.0]), ("filter.initial_pose_std", [1.0]),
    ("noise.mixture_weights", [math.nan, 1.0]), ("noise.mixture_scales", [1.0, math.inf]),
    ("association.gate_probability", 1.0)])
def test_node_parameter_build_refuses_with_the_parameter_name(name, value):
    """What the node's on-set-parameters callback runs: a refusal naming the parameter,
    never a value that is accepted and crashes the next reset."""
    with pytest.raises(ParameterError, match=name.replace(".", r"\.")):
        build({name: value})


def test_every_accepted_initial_pose_std_survives_a_reset():
    config, _ = build({"filter.initial_pose_std": [0.5, 0.5, 0.1], "filter.num_particles": 10})
    slam = OnlineEMSlam(config)
    slam.reset(initial_pose=(1.0, 2.0, 0.3))
    assert np.all(np.isfinite(slam.particles()[0]))
    SlamConfig().validate()
