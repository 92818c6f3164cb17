"""Car Park beacons over random seeds, every method: the issue-8 Car Park table.

    python docs/scripts/car_park_seeds.py BAG [--seeds 10] [--output results/car_park_seeds]

Runs ``online-em-slam run`` on the converted Car Park bag with config/hand_tuned/car_park.yaml
for each seed and method — online EM with the observed-information M-step (the
default), online EM with the seed's complete-data M-step, EKF-SLAM and
FastSLAM 2.0 — and tabulates beacons mapped, spurious landmarks, beacon RMSE
with its shape and frame parts, and the trajectory error against GPS, as mean
and standard error over seeds.  Writes ``summary.json`` and ``table.md``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

VARIANTS = {
    "online_em (observed)": ("online_em", {}),
    "online_em (observed, no FEJ)": ("online_em", {"em.first_estimate_jacobians": "false"}),
    "online_em (complete)": ("online_em", {"em.m_step": '"complete"'}),
    "ekf_slam": ("ekf_slam", {}),
    "fastslam2": ("fastslam2", {}),
}


def params_file(out: Path, name: str, overrides: dict) -> Path:
    """config/hand_tuned/car_park.yaml with ``overrides`` appended under ros__parameters."""
    text = Path("config/hand_tuned/car_park.yaml").read_text()
    lines = "".join(f"    {key}: {value}\n" for key, value in overrides.items())
    path = out / f"params-{''.join(c for c in name if c.isalnum())}.yaml"
    path.write_text(text.rstrip("\n") + "\n" + lines)
    return path


def run_one(bag: str, out: Path, name: str, seed: int) -> dict:
    method, overrides = VARIANTS[name]
    target = out / f"{name.replace(' ', '_').replace('(', '').replace(')', '')}-{seed}"
    cmd = [sys.executable, "-m", "online_em_slam.offline.cli", "run", bag, "--params",
           str(params_file(out, name, overrides)), "--output", str(target), "--seed", str(seed),
           "--method", method, "--no-plot"]
    subprocess.run(cmd, check=True, capture_output=True)
    metrics = json.loads((target / "metrics.json").read_text())
    lm, traj = metrics["landmarks"], metrics["trajectory"]
    return {"matched": lm["n_matched"], "spurious": lm["n_spurious"], "rmse": lm["rmse"],
            "shape": lm["shape_error"], "frame": lm["frame_error"], "trajectory_rmse": traj["rmse"],
            "ms_per_step": metrics["timing"]["mean_step_ms"]}


def summarise(rows: list[dict]) -> dict:
    out = {}
    for key in rows[0]:
        values = np.array([r[key] for r in rows], dtype=float)
        out[key] = {"mean": float(values.mean()), "se": float(values.std(ddof=1) / np.sqrt(len(values)))
                    if len(values) > 1 else 0.0, "min": float(values.min()), "max": float(values.max())}
    return out


def table(summary: dict, seeds: int) -> str:
    head = ("| method | seeds | beacons mapped (of 15) | spurious (max) | beacon RMSE (m) | shape (m) | frame (m) "
            "| trajectory RMSE vs GPS (m) | ms/step |\n|---|---|---|---|---|---|---|---|---|\n")
    body = ""
    for name, s in summary.items():
        body += (f"| {name} | {seeds} | {s['matched']['mean']:.1f} (min {s['matched']['min']:.0f}) | "
                 f"{s['spurious']['mean']:.1f} ({s['spurious']['max']:.0f}) | "
                 f"{s['rmse']['mean']:.3f} ± {s['rmse']['se']:.3f} | {s['shape']['mean']:.3f} ± {s['shape']['se']:.3f} | "
                 f"{s['frame']['mean']:.3f} ± {s['frame']['se']:.3f} | "
                 f"{s['trajectory_rmse']['mean']:.3f} ± {s['trajectory_rmse']['se']:.3f} | "
                 f"{s['ms_per_step']['mean']:.2f} |\n")
    return head + body


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--methods", nargs="+", default=list(VARIANTS))
    parser.add_argument("--output", default="results/car_park_seeds")
    args = parser.parse_args()
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    summary = {}
    for name in args.methods:
        rows = [run_one(args.bag, out, name, seed) for seed in range(args.seeds)]
        summary[name] = summarise(rows)
        print(name, json.dumps({k: round(v["mean"], 3) for k, v in summary[name].items()}), flush=True)
    text = table(summary, args.seeds)
    print(text)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "table.md").write_text(text)


if __name__ == "__main__":
    main()
