"""``online-em-slam compare BAG --fleet``: the fleet's joint map next to its batch optimum.

Online EM's fleet run (:func:`.fleet_runner.run_fleet`, DIR/online_em_fleet/) and the GTSAM batch
over every robot's data (:func:`.fleet_batch.solve_and_score`, known ids) with the parameter
files' noise (DIR/batch_fleet_params/) and with the noise each robot learned in the run
(DIR/batch_fleet_learned/), as the MRCLAM benchmark's (P) and (L).  The single-robot baselines
(EKF-SLAM, FastSLAM 2.0) have no fleet form and are not run.  DIR/comparison.md and .json hold
the joint map's scores and each robot's trajectory RMSE per method.
"""
from __future__ import annotations

from pathlib import Path

from . import report
from .fleet_batch import solve_and_score
from .fleet_runner import fleet_initial_poses, fleet_summary, read_fleet_inputs, run_fleet


def cmd_compare_fleet(args, config, settings, file_values: dict, extra: dict) -> int:
    """After the parameter files are read (cli.py)."""
    inputs = read_fleet_inputs(args.bag, settings)
    if not any(len(robot.events) for robot in inputs.robots):
        raise ValueError(f"{args.bag}: no inputs on the robots' configured topics")
    out = Path(args.output)
    initial = fleet_initial_poses(args.initial_pose, inputs, config, settings, file_values)
    online = run_fleet(inputs, config, settings, initial, out / "online_em_fleet", plot=not args.no_plot,
                       match_gate=args.match_gate, align=args.align, extra=extra, param_values=file_values)
    print(fleet_summary(online), flush=True)
    runs = [("online_em_fleet", online)]
    for label, noise_from in (("params", None), ("learned", out / "online_em_fleet")):
        metrics = solve_and_score(inputs, list(args.params), None if noise_from is None else str(noise_from),
                                  out / f"batch_fleet_{label}", args.match_gate)
        runs.append((f"batch_fleet_{label}", metrics))
    rows = [comparison_row(name, metrics) for name, metrics in runs]
    report.json_dump(out / "comparison.json", {"bag": str(args.bag), "params": extra.get("params"),
                                               "seed": config.filter.seed, "robots": inputs.names,
                                               "methods": rows})
    (out / "comparison.md").write_text(comparison_markdown(rows, inputs.names, str(args.bag)))
    print((out / "comparison.md").read_text())
    return 0


def comparison_row(name: str, metrics: dict) -> dict:
    lm = metrics.get("landmarks") or {}
    return {"method": name, "within_gate": lm.get("n_matched"), "n_true": lm.get("n_true"),
            "spurious": lm.get("n_spurious"), "rmse": lm.get("rmse"), "shape": lm.get("shape_error"),
            "trajectory_rmse": {robot: (m.get("trajectory") or {}).get("rmse")
                                for robot, m in metrics.get("robots", {}).items()}}


def comparison_markdown(rows: list[dict], robots: list[str], bag: str) -> str:
    head = ["method", "within gate", "spurious", "map RMSE (m)", "shape (m)"] + [f"{r} traj. (m)" for r in robots]
    lines = [f"# Fleet comparison: {bag}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [row["method"], f"{row['within_gate']}/{row['n_true']}", str(row["spurious"]),
                 report._fmt(row["rmse"]), report._fmt(row["shape"])]
        cells += [report._fmt(row["trajectory_rmse"].get(r)) for r in robots]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
