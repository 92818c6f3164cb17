"""The seed-scenario benchmark's tables and plots: per-run records -> summaries (mean and
standard error per method), paired differences, markdown tables, convergence and laps plots."""
from __future__ import annotations

import json
import math
import os

import numpy as np

from .methods import ALL_METHODS, SCORES


def mean_and_se(values) -> tuple[float, float]:
    """Mean and standard error of the mean over the finite values (se NaN below 2)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan
    return float(v.mean()), float(v.std(ddof=1) / math.sqrt(v.size)) if v.size > 1 else math.nan


def group_key(row: dict) -> tuple[str, int]:
    return row["method"], row.get("laps") or 0


def _in_method_order(groups: dict) -> list:
    """Items of a dict keyed by (method, laps), in the order of ALL_METHODS, then laps."""
    order = {m: i for i, m in enumerate(ALL_METHODS)}
    return sorted(groups.items(), key=lambda item: (order.get(item[0][0], len(order)), item[0][1]))


def summarize(results: list[dict]) -> list[dict]:
    """One row per (method, laps): mean and standard error of every score over the seeds."""
    groups: dict[tuple[str, int], list[dict]] = {}
    for row in results:
        groups.setdefault(group_key(row), []).append(row)
    table = []
    for (method, laps), rows in _in_method_order(groups):
        col = lambda key: np.array([r[key] for r in rows], dtype=float)  # noqa: E731
        summary = {"method": method, "laps": laps or None, "runs": len(rows), "n_steps": rows[0].get("n_steps")}
        for key in SCORES + ("p99_step_ms", "mean_nees", "mean_true_pose_loglik"):
            summary[f"{key}_mean"], summary[f"{key}_se"] = mean_and_se(col(key))
        summary["landmark_rmse_median"] = float(np.median(col("landmark_rmse")))
        summary["landmark_rmse_std"] = float(np.std(col("landmark_rmse")))
        table.append(summary)
    return table


def _pm(row: dict, key: str, digits: int = 3) -> str:
    mean, se = row[f"{key}_mean"], row[f"{key}_se"]
    text = "n/a" if not math.isfinite(mean) else f"{mean:.{digits}f}"
    return text if not math.isfinite(se) else f"{text} ± {se:.{digits}f}"


def format_table(table: list[dict]) -> str:
    """Seed-run table: scores with their standard errors, timing and consistency."""
    header = ("| method | runs | landmark RMSE (m) | median | shape (m) | frame (m) | pose RMSE (m) "
              "| mean step (ms) | p99 step (ms) | mean NEES (3 dof) | mean log-lik of true pose |")
    lines = [header, "|" + "---|" * 11]
    for row in table:
        lines.append(f"| {row['method']} | {row['runs']} | {_pm(row, 'landmark_rmse')} "
                     f"| {row['landmark_rmse_median']:.3f} | {_pm(row, 'shape_error')} | {_pm(row, 'frame_error')} "
                     f"| {_pm(row, 'pose_rmse')} | {row['mean_step_ms_mean']:.3f} | {row['p99_step_ms_mean']:.3f} "
                     f"| {row['mean_nees_mean']:.2f} | {row['mean_true_pose_loglik_mean']:.2f} |")
    return "\n".join(lines)


def format_laps_table(table: list[dict], laps: list[int]) -> str:
    """Long-run table: one row per method and requested lap count, mean ± se."""
    header = ("| method | laps | runs | steps | landmark RMSE (m) | shape (m) | frame (m) | pose RMSE (m) "
              "| mean step (ms) |")
    lines = [header, "|" + "---|" * 9]
    for row in table:
        if row["laps"] in laps:
            lines.append(f"| {row['method']} | {row['laps']} | {row['runs']} | {row['n_steps']} "
                         f"| {_pm(row, 'landmark_rmse')} | {_pm(row, 'shape_error')} | {_pm(row, 'frame_error')} "
                         f"| {_pm(row, 'pose_rmse')} | {row['mean_step_ms_mean']:.3f} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- paired comparison

def paired_differences(runs_a: list[dict], runs_b: list[dict]) -> list[dict]:
    """B - A per (method, laps) over the seeds present in both: mean and
    standard error of the per-seed differences of every score (the seeds share
    the simulated noise, so pairing removes the between-seed variance)."""
    index_a = {group_key(r) + (r["seed"],): r for r in runs_a}
    groups: dict[tuple[str, int], list[tuple[dict, dict]]] = {}
    for rb in runs_b:
        ra = index_a.get(group_key(rb) + (rb["seed"],))
        if ra is not None:
            groups.setdefault(group_key(rb), []).append((ra, rb))
    table = []
    for (method, laps), pairs in _in_method_order(groups):
        row = {"method": method, "laps": laps or None, "runs": len(pairs)}
        for key in SCORES:
            a = np.array([p[0][key] for p in pairs], dtype=float)
            b = np.array([p[1][key] for p in pairs], dtype=float)
            row[f"{key}_a"], row[f"{key}_b"] = float(np.nanmean(a)), float(np.nanmean(b))
            row[f"{key}_mean"], row[f"{key}_se"] = mean_and_se(b - a)
        table.append(row)
    return table


def format_paired(table: list[dict], name_a: str, name_b: str) -> str:
    lines = [f"Paired differences {name_b} - {name_a} (mean ± se over seeds; negative: {name_b} better)", "",
             "| method | laps | pairs | landmark RMSE A -> B (m) | diff | shape diff | frame diff "
             "| pose RMSE diff | step ms diff |", "|" + "---|" * 9]
    for row in table:
        lines.append(f"| {row['method']} | {row['laps'] or '-'} | {row['runs']} "
                     f"| {row['landmark_rmse_a']:.3f} -> {row['landmark_rmse_b']:.3f} | {_pm(row, 'landmark_rmse')} "
                     f"| {_pm(row, 'shape_error')} | {_pm(row, 'frame_error')} | {_pm(row, 'pose_rmse')} "
                     f"| {_pm(row, 'mean_step_ms')} |")
    return "\n".join(lines)


def compare_files(path_a: str, path_b: str) -> str:
    """Paired-difference table B - A of two results files, at B's requested laps."""
    with open(path_a) as ha, open(path_b) as hb:
        a, b = json.load(ha), json.load(hb)
    name = lambda data, path: data.get("meta", {}).get("tag") or os.path.basename(path)  # noqa: E731
    requested = set(b.get("meta", {}).get("laps") or [])
    runs_b = [r for r in b["runs"] if not requested or r.get("laps") in requested]
    return format_paired(paired_differences(a["runs"], runs_b), name(a, path_a), name(b, path_b))


# --------------------------------------------------------------------------- plots

def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_curves(results: list[dict], path: str, dt: float) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    # Methods outside ALL_METHODS: variants relabelled when several results files are merged.
    for method in ALL_METHODS + tuple(sorted({r["method"] for r in results} - set(ALL_METHODS))):
        curves = [r["error_curve"] for r in results if r["method"] == method and r["error_curve"]]
        if not curves:
            continue
        mean = np.nanmean(np.array(curves, dtype=float), axis=0)
        ax.plot(np.arange(1, mean.size + 1) * dt, mean, label=method)
    gtsam = [r["landmark_rmse"] for r in results if r["method"] == "gtsam_batch"]
    if gtsam:
        ax.axhline(float(np.mean(gtsam)), color="k", linestyle="--", label="gtsam_batch (final)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("landmark RMSE over mapped landmarks (m)")
    ax.set_title("Mean landmark error against time (seed figure 2)")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_laps(table: list[dict], path: str, title: str = "") -> None:
    """Landmark RMSE, shape and frame error against laps, mean ± se, one line per method."""
    plt = _pyplot()
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.5), sharey=True)
    for method in ALL_METHODS:
        rows = [r for r in table if r["method"] == method and r["laps"]]
        if not rows:
            continue
        laps = [r["laps"] for r in rows]
        for ax, key in zip(axes, ("landmark_rmse", "shape_error", "frame_error")):
            # GTSAM is solved at the requested laps only: dashed, the points are what counts.
            ax.errorbar(laps, [r[f"{key}_mean"] for r in rows], yerr=[r[f"{key}_se"] for r in rows],
                        marker="o", markersize=3, capsize=2, label=method,
                        linestyle="--" if method == "gtsam_batch" else "-")
    for ax, name in zip(axes, ("landmark RMSE", "shape (after the best rigid fit)", "frame")):
        ax.set_title(name)
        ax.set_xlabel("laps of the route")
        ax.set_yscale("log")
        ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("error (m), mean ± se over seeds")
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------- command line
