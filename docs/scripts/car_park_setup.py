"""What the live Car Park scripts (soak.py, input_path_figures.py) share: the converted bag,
config/hand_tuned/car_park.yaml read for a seed, and the GPS-derived initial pose of ``online-em-slam run``."""
from __future__ import annotations

from pathlib import Path

PARAMS = Path(__file__).resolve().parents[2] / "config" / "hand_tuned" / "car_park.yaml"


def car_park(out: Path, seed: int = 0):
    """(bag, params path, file values, SlamConfig, NodeSettings, bag inputs, initial pose); the
    bag is converted into ``out/car_park_bag`` the first time."""
    from online_em_slam.datasets.kth.convert import convert
    from online_em_slam.parameters.yaml_file import config_from_params, load_params
    from online_em_slam.offline.runner import choose_initial_pose, read_inputs

    out.mkdir(parents=True, exist_ok=True)
    bag = out / "car_park_bag"
    if not bag.exists():
        convert("car_park", bag, progress=False)
    values = load_params(PARAMS)
    config, settings = config_from_params(values, {"filter.seed": seed})
    inputs = read_inputs(bag, settings)
    initial = choose_initial_pose("gps", inputs, config, settings, values)
    return bag, PARAMS, values, config, settings, inputs, initial
