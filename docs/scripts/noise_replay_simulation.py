"""Warm-up replay in simulation: landmark RMSE and shape with and without the replay, paired.

    python docs/scripts/noise_replay_simulation.py 1,2,3,4,5,6,7,8

The scenario of test/test_noise_learning.py (40 landmarks, 10 % outliers at 25 R,
N = 50) for each seed: the run given the true noise, then started 3x too large
and 3x too small with learning on, without and with ``noise_learning.replay_warmup``.
Prints one line per seed and start: seed, factor, truth RMSE and shape, then
RMSE, shape, replayed, CPU seconds for each variant
(docs/measurements/noise_replay_simulation.txt).
"""
import sys, time
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2] / "test"))
from dataclasses import replace
from test_noise_learning import TRUTH, PARTICLES, run, map_errors, started_wrong, true_motion_scale
from online_em_slam.experiments.simulation import ScenarioConfig, simulate, slam_config_for
from online_em_slam.core.config import replace_section
import numpy as np
rows = []
for seed in [int(s) for s in sys.argv[1].split(",")]:
    scenario = simulate(ScenarioConfig(seed=seed, outlier_probability=0.1, **TRUTH))
    base = slam_config_for(scenario, num_particles=PARTICLES)
    truth = map_errors(run(scenario, base), scenario)
    for factor in (3.0, 1/3):
        out = [seed, factor, *truth]
        for replay in (False, True):
            cfg = started_wrong(base, factor)
            cfg = replace_section(cfg, noise_learning=replace(cfg.noise_learning, replay_warmup=replay))
            t = time.process_time(); slam = run(scenario, cfg); t = time.process_time() - t
            out += [*map_errors(slam, scenario), int(slam.learned_noise()["warmup_replayed"]), t]
        print(" ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in out), flush=True)
