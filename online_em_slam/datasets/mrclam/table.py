"""The MRCLAM benchmark's tables (:mod:`online_em_slam.datasets.mrclam.benchmark`): records -> markdown.

A *cell* is one method with one noise setting on one run (dataset, robot, seconds, ids),
summarised over its seeds: landmark RMSE after the rigid fit (shape) and in the
ground-truth frame, mean ± standard error (known ids: over every landmark, paired by id);
landmarks within 1 m, the minimum (in the ground-truth frame, and once the map is moved by
its best rigid fit: the map's frame comes from the start pose and the first heading drift,
its shape from everything after); spurious landmarks, the maximum; trajectory RMSE (as published, and as
the replays filtered it again: online EM's best estimate of the past); wall time.  A baseline shows the better of its
two noise settings: more landmarks within 1 m (worst seed), then the lower mean shape RMSE.
"""
from __future__ import annotations

import math

import numpy as np

#: Statuses of a work item whose result is there (run now, reused, or its map scored again).
DONE = ("ok", "reused", "rescored")
METHODS = ("online_em", "online_em_complete", "ekf_slam", "fastslam2", "marginal_slam", "batch")
BASELINES = ("ekf_slam", "fastslam2", "marginal_slam")
TWO_NOISE = BASELINES + ("batch",)                  # run with the params' noise and with the learned one

NOISE_TAG = {"params": "P", "learned": "L"}
LEGEND = ("Cells: landmark RMSE after the best rigid 2-D fit (shape, m), mean ± standard error over seeds · "
          "landmarks within 1 m in the ground-truth frame (worst seed) / surveyed · spurious landmarks (worst "
          "seed). Known ids: every estimate paired with the surveyed landmark of its id, so every landmark's "
          "error counts; unknown ids: paired by position within 1 m. "
          "Baselines and batch: the better of their two noise settings (more landmarks within 1 m, then lower "
          "shape RMSE), tagged (P) params file noise or (L) the noise online EM learned on that run and seed "
          "(batch and EKF-SLAM on the params' noise: deterministic, one run). Batch: GTSAM's maximum a posteriori "
          "of the estimator's model (the scans the travel rule keeps, the Student-t's likelihood), known ids. "
          "n/a: not run, failed or unavailable.")


def mean_se(values) -> tuple[float, float]:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan


def _extreme(values, pick):
    v = [x for x in values if x is not None]
    return pick(v) if v else None


def cells(records: list[dict]) -> dict[tuple, dict]:
    """(seconds, ids, dataset, robot, method, noise) -> the cell over the successful seeds."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        if r["kind"] != "convert" and r["status"] in DONE:
            key = (r["seconds"], r["ids"], r["dataset"], r["robot"], r["method"], r["noise"])
            groups.setdefault(key, []).append(r)
    out = {}
    for key, rows in groups.items():
        col = lambda name: [r.get(name) for r in rows]  # noqa: E731
        cell = {"noise": key[-1], "seeds": len(rows), "matched_min": _extreme(col("matched"), min),
                "matched_fitted_min": _extreme(col("matched_fitted"), min),
                "n_true": _extreme(col("n_true"), max), "spurious_max": _extreme(col("spurious"), max),
                "item_wall_s": mean_se(col("item_wall_s"))[0]}
        for name in ("landmark_shape", "landmark_rmse", "trajectory_rmse", "trajectory_revised_rmse", "landmark_scale",
                     "landmark_shape_scaled"):
            cell[name], cell[name + "_se"] = mean_se(col(name))
        out[key] = cell
    return out


def _rank(cell: dict) -> tuple:
    shape = cell["landmark_shape"]
    return -(cell["matched_min"] or 0), shape if math.isfinite(shape) else math.inf


def best_cell(table: dict, run: tuple, method: str) -> dict | None:
    """The method's cell on ``run`` (seconds, ids, dataset, robot): the better noise setting for a baseline."""
    options = [table[run + (method, noise)] for noise in ("params", "learned") if run + (method, noise) in table]
    return min(options, key=_rank) if options else None


def _num(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _pm(cell: dict, name: str) -> str:
    se = cell[name + "_se"]
    return _num(cell[name]) + ("" if not math.isfinite(se) else f" ± {_num(se)}")


def format_cell(cell: dict | None, method: str) -> str:
    if cell is None:
        return "n/a"
    tag = f" ({NOISE_TAG[cell['noise']]})" if method in TWO_NOISE else ""
    return f"{_pm(cell, 'landmark_shape')}{tag} · {cell['matched_min']}/{cell['n_true']} · {cell['spurious_max']}"


def _row(values) -> str:
    return "| " + " | ".join(str(v) for v in values) + " |"


def _header(first: list[str], methods: list[str]) -> list[str]:
    return [_row(first + methods), "|" + "---|" * (len(first) + len(methods))]


def run_label(run: tuple) -> list[str]:
    return [str(run[2]), str(run[3])]


def main_table(table: dict, runs: list[tuple], methods: list[str]) -> list[str]:
    lines = _header(["dataset", "robot"], methods)
    for run in runs:
        lines.append(_row(run_label(run) + [format_cell(best_cell(table, run, m), m) for m in methods]))
    return lines


def frame_table(table: dict, runs: list[tuple], methods: list[str]) -> list[str]:
    """Landmark RMSE in the ground-truth frame and trajectory RMSE, same cells as the main table."""
    lines = _header(["dataset", "robot"], methods)
    for run in runs:
        row = []
        for m in methods:
            c = best_cell(table, run, m)
            row.append("n/a" if c is None else f"{_pm(c, 'landmark_rmse')} / {_pm(c, 'trajectory_rmse')}")
        lines.append(_row(run_label(run) + row))
    return lines


def timing_table(table: dict, runs: list[tuple], methods: list[str]) -> list[str]:
    """Wall time of one work item (bag reading included), mean over seeds, per noise setting."""
    lines = _header(["dataset", "robot"], methods)
    for run in runs:
        row = []
        for m in methods:
            parts = [f"{NOISE_TAG[n]} {_num(table[run + (m, n)]['item_wall_s'], 1)}" if m in TWO_NOISE else
                     _num(table[run + (m, n)]['item_wall_s'], 1)
                     for n in ("params", "learned") if run + (m, n) in table]
            row.append(" / ".join(parts) or "n/a")
        lines.append(_row(run_label(run) + row))
    return lines


def _shape(table: dict, run: tuple, method: str) -> float:
    c = best_cell(table, run, method)
    return math.nan if c is None else c["landmark_shape"]


def summary_block(records: list[dict], table: dict, runs: list[tuple], methods: list[str]) -> list[str]:
    lines = ["Mean over runs (each run: its mean over seeds; baselines at their better noise setting):", "",
             _row(["method", "runs", "shape RMSE (m)", "GT-frame RMSE (m)", "trajectory RMSE (m)",
                   "trajectory as the replays filtered it again (m)",
                   "within 1 m (worst seed)", "within 1 m after the fit (worst seed)", "spurious (worst seed)",
                   "map scale", "shape without the scale (m)"]),
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in methods:
        found = [c for c in (best_cell(table, run, m) for run in runs) if c is not None]
        if not found:
            lines.append(_row([m, 0] + ["n/a"] * 9))
            continue
        mean = lambda name: _num(mean_se([c.get(name) for c in found])[0])  # noqa: E731
        lines.append(_row([m, len(found), mean("landmark_shape"), mean("landmark_rmse"), mean("trajectory_rmse"),
                           mean("trajectory_revised_rmse"),
                           _num(mean_se([c["matched_min"] for c in found])[0], 1),
                           _num(mean_se([c["matched_fitted_min"] for c in found])[0], 1),
                           _num(mean_se([c["spurious_max"] for c in found])[0], 1),
                           mean("landmark_scale"), mean("landmark_shape_scaled")]))
    lines.append("")
    lines += comparisons(table, runs)
    lines.append(paired_with_better_baseline(records, table, runs))
    lines.append("")
    lines += checks(table, runs, methods)
    return lines


def comparisons(table: dict, runs: list[tuple]) -> list[str]:
    """Online EM against the better of EKF-SLAM and FastSLAM 2.0, and against batch (shape RMSE)."""
    wins, compared, ratios = 0, 0, []
    for run in runs:
        em = _shape(table, run, "online_em")
        better = better_baseline(table, run)
        if math.isfinite(em) and better is not None:
            compared += 1
            wins += em <= better[1]["landmark_shape"]
        batch = _shape(table, run, "batch")
        if math.isfinite(em) and math.isfinite(batch) and batch > 0:
            ratios.append(em / batch)
    ratio = f"{np.mean(ratios):.2f} over {len(ratios)} runs" if ratios else "n/a (no batch results)"
    return [f"- online EM shape RMSE <= the better of EKF-SLAM and FastSLAM 2.0: {wins} of {compared} runs",
            f"- online EM / batch shape RMSE ratio (mean over runs): {ratio}"]


def better_baseline(table: dict, run: tuple) -> tuple[str, dict] | None:
    """(method, cell) of the better of EKF-SLAM and FastSLAM 2.0 on ``run``, each at its better noise
    setting, by shape RMSE: what :func:`comparisons` and :func:`paired_with_better_baseline` compare with."""
    found = [(m, c) for m in ("ekf_slam", "fastslam2") if (c := best_cell(table, run, m)) is not None
             and math.isfinite(c["landmark_shape"])]
    return min(found, key=lambda mc: mc[1]["landmark_shape"]) if found else None


def paired_with_better_baseline(records: list[dict], table: dict, runs: list[tuple]) -> str:
    """Online EM minus the better baseline, seed by seed: on the learned noise a baseline's seed k ran
    on online EM's seed k's noise, so the two are paired; on the params' noise, a deterministic
    baseline's one run is each seed's.  Ahead / behind: the mean difference beyond two standard
    errors of it, level within; with one pair, its sign."""
    shape = {(r["seconds"], r["ids"], r["dataset"], r["robot"], r["method"], r["noise"], r["seed"]):
             r["landmark_shape"] for r in records
             if r["kind"] != "convert" and r["status"] in DONE and r.get("landmark_shape") is not None}
    by_cell: dict[tuple, dict] = {}
    for key, value in shape.items():
        by_cell.setdefault(key[:-1], {})[key[-1]] = value
    counts = {"ahead": 0, "level": 0, "behind": 0}
    for run in runs:
        better = better_baseline(table, run)
        if better is None:
            continue
        method, cell = better
        ours = by_cell.get(run + ("online_em", "params"), {})
        theirs = by_cell.get(run + (method, cell["noise"]), {})
        single = next(iter(theirs.values())) if len(theirs) == 1 and cell["noise"] == "params" else None
        d = [v - theirs.get(seed, single) for seed, v in ours.items() if theirs.get(seed, single) is not None]
        mean, se = mean_se(d)
        if not math.isfinite(mean):
            continue
        margin = 2.0 * se if math.isfinite(se) else 0.0
        counts["ahead" if mean < -margin else "behind" if mean > margin else "level"] += 1
    return (f"- online EM minus the better of EKF-SLAM and FastSLAM 2.0, paired by seed (beyond two standard "
            f"errors): ahead on {counts['ahead']}, level on {counts['level']}, behind on {counts['behind']} runs")


def checks(table: dict, runs: list[tuple], methods: list[str]) -> list[str]:
    """One line per run: all landmarks within 1 m and no spurious landmark, on every seed."""
    lines = ["All landmarks within 1 m / no spurious landmark on every seed (✓ yes, ✗ no):", ""]
    for run in runs:
        parts = []
        for m in methods:
            c = best_cell(table, run, m)
            if c is not None and c["matched_min"] is not None:
                full = "✓" if c["matched_min"] == c["n_true"] else "✗"
                clean = "✓" if c["spurious_max"] == 0 else "✗"
                fitted = "" if c["matched_fitted_min"] is None else f" ({c['matched_fitted_min']} after the fit)"
                parts.append(f"{m} {c['matched_min']}/{c['n_true']}{fitted} {full}, {c['spurious_max']} spurious "
                             f"{clean}")
        lines.append(f"- dataset {run[2]} robot {run[3]}: " + ("; ".join(parts) or "no results"))
    return lines


def failures(records: list[dict]) -> list[str]:
    bad = [r for r in records if r["status"] not in DONE]
    if not bad:
        return []
    lines = ["## Work items without a result", ""]
    lines += [f"- `{r['key']}`: {r['status']}" + (f" ({r['error']})" if r["error"] else "") for r in bad]
    return lines + [""]


def results_markdown(records: list[dict], meta: dict) -> str:
    table = cells(records)
    methods = [m for m in METHODS if m in meta["methods"]]
    lines = ["# MRCLAM benchmark", "",
             f"Datasets {meta['datasets']}, robots {meta['robots']}, seeds {meta['seeds']}, params "
             f"{', '.join(meta['params'])}; match gate {meta['match_gate_m']} m; this invocation took "
             f"{meta['wall_time_s']:.0f} s with {meta['jobs']} jobs ({meta['date']}; reused results cost nothing).",
             "", LEGEND, ""]
    for seconds, ids in sorted({(r["seconds"], r["ids"]) for r in records}):
        runs = sorted({k[:4] for k in table if k[:2] == (seconds, ids)})
        title = f"{seconds} s" if seconds else "full length"
        title += f" from {meta['start']} s" if meta.get("start") else ""
        lines += [f"## {title}, {ids} ids", ""] + main_table(table, runs, methods) + [""]
        lines += ["Landmark RMSE in the ground-truth frame / trajectory RMSE against /ground_truth/position (m):", ""]
        lines += frame_table(table, runs, methods) + [""]
        lines += ["Wall time per work item (s, bag reading included, mean over seeds):", ""]
        lines += timing_table(table, runs, methods) + [""]
        lines += summary_block(records, table, runs, methods) + [""]
    lines += failures(records)
    return "\n".join(lines).rstrip("\n") + "\n"
