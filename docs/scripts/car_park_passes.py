"""Beacon RMSE on Car Park after repeated EM passes (docs/RESULTS.md).

    online-em-slam-convert car_park out/cp_bag
    python docs/scripts/car_park_passes.py out/cp_bag [SEEDS [PASSES]]
"""
import sys

from online_em_slam.parameters.yaml_file import config_from_params, load_params
from online_em_slam.offline.report import evaluate
from online_em_slam.offline.runner import choose_initial_pose, feed, make_estimator, read_inputs

bag = sys.argv[1] if len(sys.argv) > 1 else "out/cp_bag"
file_values = load_params("config/hand_tuned/car_park.yaml")
config, settings = config_from_params(file_values)
inputs = read_inputs(bag, settings)
initial = choose_initial_pose("auto", inputs, config, settings, file_values)
for seed in range(int(sys.argv[2]) if len(sys.argv) > 2 else 5):
    seeded, _ = config_from_params(file_values, {"filter.seed": seed})
    slam = make_estimator("online_em", seeded, initial.pose)
    figures = []
    for index in range(int(sys.argv[3]) if len(sys.argv) > 3 else 8):
        if index:
            slam.start_new_pass(initial.pose, None)
        metrics = evaluate(feed(slam, inputs), inputs, seeded)["landmarks"]
        figures.append((round(metrics["rmse"], 3), metrics["n_spurious"]))
    print("seed", seed, "beacon RMSE, spurious after passes 1-8:", figures, flush=True)
