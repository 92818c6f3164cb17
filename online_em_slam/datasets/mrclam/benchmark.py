"""Every method on the UTIAS MRCLAM runs: one command, resumable, one table.

    online-em-slam-mrclam-benchmark --data-dir /work/shared/datasets/mrclam --output results/mrclam
        [--datasets 1 9] [--robots 1 2 3 4 5] [--seconds 600]   (0 = full length; several allowed)
        [--start 0]   (the runs start S0 seconds after each robot's first odometry sample)
        [--seeds 0 1 2 3 4] [--ids known unknown] [--methods online_em online_em_complete ekf_slam
        fastslam2 marginal_slam batch] [--params config/mrclam.yaml ...] [--jobs 2] [--particles N]
        [--compare-with A/results.json]
    online-em-slam-mrclam-benchmark --compare A/results.json B/results.json [--seeds 2 3 4]

For every run (dataset, robot, seconds, ids) the bag is converted once into
``OUTPUT/bags/<run>/`` (an existing bag is reused), then every method runs on it
(``OUTPUT/runs/<run>/<method>[_learned]/seed<k>/``, the offline runner's outputs):

* ``online_em``: the params as they are; ``online_em_complete``: em.m_step complete;
* ``fastslam2``, ``marginal_slam``: every seed, twice: with the params' noise and with the
  noise online EM learned on the same run and seed (its noise.yaml as a second params
  file; ``_learned``); ``ekf_slam``: the same, but deterministic with the params' noise,
  so that setting runs once (the first seed);
* ``batch``: GTSAM batch maximum a posteriori of the estimator's model (offline/batch.py:
  the scans the travel rule keeps, the Student-t's likelihood), known ids only (skipped for
  unknown ids), as ``ekf_slam``: the params' noise once, the learned noise of every seed.

Each seed's online EM learns its own noise, so a baseline on the learned noise is as
random as online EM's map, and is run and averaged over the same seeds, paired.

The learned variants wait for their online EM run (and are left out when online_em is
not among the methods and its noise.yaml does not exist yet).  Landmark metrics match
by id for known ids (every landmark's error counts; ``matched`` = landmarks within 1 m of
their surveyed position) and by position for unknown ids (Hungarian assignment within
1 m); shape = RMSE after the best rigid 2-D fit; frame = the rest; trajectory RMSE
against /ground_truth/position.  ``--rescore`` scores existing runs' maps again.
Work items run in ``--jobs`` spawned worker processes with one BLAS thread each; an
existing metrics.json is reused (an interrupted sweep resumes).  Plots only for the
first seed of online_em and ekf_slam.  Writes ``OUTPUT/results.json`` (every work item)
and ``OUTPUT/results.md`` (tables: :mod:`online_em_slam.datasets.mrclam.table`), and prints the markdown.
``--compare-with FILE`` then prints the paired differences of this run against another
results.json (the same runs, methods and seeds; :mod:`online_em_slam.datasets.mrclam.paired`),
``--compare A B`` those of two existing files, without running anything (``--seeds``: over those
seeds only; the defaults were chosen on seeds 0-1, so a change made there is confirmed on others).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

from .paired import compare_files
from .table import DONE, METHODS, TWO_NOISE, results_markdown

MATCH_GATE = 1.0
ARCHIVE_SUFFIXES = (".zip", ".tar.xz", ".tar.gz", ".tar")    # a dataset's archive, after its directory
DEFAULT_SEEDS = [0, 1, 2, 3, 4]                        # particle methods over five seeds, as the issue asks
SINGLE_RUN = ("ekf_slam", "batch")                   # deterministic on the params' noise: the first seed only
RUNNER_METHOD = {"online_em_complete": "online_em"}
OVERRIDES = {"online_em_complete": (("em.m_step", "complete"),)}
PLOTTED = ("online_em", "ekf_slam")
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: The package's config/mrclam.yaml (source checkout); else looked up from the working directory.
_CHECKOUT_PARAMS = Path(__file__).resolve().parents[3] / "config" / "mrclam.yaml"
DEFAULT_PARAMS = str(_CHECKOUT_PARAMS) if _CHECKOUT_PARAMS.exists() else "config/mrclam.yaml"


@dataclass(frozen=True)
class Item:
    """One work item (picklable): a bag conversion, an offline run or a batch solve."""

    key: str
    kind: str                                # convert | run | batch
    run: str                                 # <dataset>_r<robot>_<seconds>[_from<start>s]_<ids>
    dataset: int
    robot: int
    seconds: int
    ids: str
    bag: str
    method: str = ""
    noise: str = "params"                    # params | learned
    seed: int | None = None
    out: str = ""
    params: tuple[str, ...] = ()
    overrides: tuple = ()
    plot: bool = False
    source: str = ""                         # dataset directory or archive (convert)
    particles: int | None = None             # --particles (filter.num_particles)
    after: tuple[str, ...] = ()              # keys of the items this one needs
    rescore: bool = False                    # --rescore: an existing run's map scored again
    start: int = 0                           # --start: seconds after the first odometry sample


# --------------------------------------------------------------------------- planning

def run_name(dataset: int, robot: int, seconds: int, ids: str, start: int = 0) -> str:
    return f"{dataset}_r{robot}_{f'{seconds}s' if seconds else 'full'}{f'_from{start}s' if start else ''}_{ids}"


def dataset_source(data_dir: Path, dataset: int) -> Path:
    """data_dir/MRCLAM_DatasetN (directory), else its archive: .zip (as the dataset's site offers it),
    .tar.xz, .tar.gz or .tar."""
    name = f"MRCLAM_Dataset{dataset}"
    for candidate in (data_dir / name, *(data_dir / f"{name}{ext}" for ext in ARCHIVE_SUFFIXES)):
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f"{data_dir}: no {name} directory or {name}{{{','.join(ARCHIVE_SUFFIXES)}}}")


def plan(args) -> list[Item]:
    """Every work item, each after the items it needs (dependency order)."""
    items: list[Item] = []
    output = Path(args.output)
    for dataset in args.datasets:
        source = dataset_source(Path(args.data_dir), dataset)
        for robot in args.robots:
            for seconds in args.seconds:
                for ids in args.ids:
                    name = run_name(dataset, robot, seconds, ids, args.start)
                    convert = Item(f"{name}/bag", "convert", name, dataset, robot, seconds, ids,
                                   str(output / "bags" / name), source=str(source), particles=args.particles,
                                   rescore=args.rescore, start=args.start)
                    items.append(convert)
                    items.extend(run_items(args, convert, output / "runs" / name))
    return items


def run_items(args, convert: Item, root: Path) -> list[Item]:
    """The method runs on one converted bag: the params' noise first, then the learned variants."""
    seeds = args.seeds or DEFAULT_SEEDS
    first, plain, learned = seeds[0], [], []
    for method in args.methods:
        if method == "batch" and convert.ids != "known":
            continue
        for seed in seeds:
            item = replace(convert, key=f"{convert.run}/{method}/seed{seed}", kind="batch" if method == "batch"
                           else "run", method=method, seed=seed, out=str(root / method / f"seed{seed}"),
                           params=tuple(args.params), overrides=OVERRIDES.get(method, ()),
                           plot=method in PLOTTED and seed == first, after=(convert.key,))
            if seed == first or method not in SINGLE_RUN:
                plain.append(item)
            if method in TWO_NOISE:
                learned.append(learned_variant(args, item, root))
    return plain + [item for item in learned if item is not None]


def learned_variant(args, item: Item, root: Path) -> Item | None:
    """``item`` with the noise online EM learned on the same run and seed (None: not available)."""
    source = f"{item.run}/online_em/seed{item.seed}"
    noise = root / "online_em" / f"seed{item.seed}" / "noise.yaml"
    if "online_em" not in args.methods and not noise.exists():
        return None
    after = item.after + ((source,) if "online_em" in args.methods else ())
    return replace(item, key=f"{item.run}/{item.method}_learned/seed{item.seed}", noise="learned",
                   out=str(root / f"{item.method}_learned" / f"seed{item.seed}"),
                   params=item.params + (str(noise),), plot=False, after=after)


# --------------------------------------------------------------------------- work items

def execute(item: Item) -> dict:
    """Do one work item (in a worker); its record, reusing an earlier result when there is one."""
    started = time.perf_counter()
    try:
        if item.kind == "convert":
            status = convert_bag(item)
            return record(item, status, {"benchmark": {"item_wall_s": time.perf_counter() - started}})
        path = Path(item.out) / "metrics.json"
        if path.exists() and item.rescore:
            metrics = rescored(item, json.loads(path.read_text()))
            from ...offline.report import json_dump
            json_dump(path, metrics)
            return record(item, "rescored", metrics)
        if path.exists():
            return record(item, "reused", json.loads(path.read_text()))
        metrics = solve_batch(item) if item.kind == "batch" else run_method(item)
        metrics["benchmark"] = {"item_wall_s": time.perf_counter() - started, "params": list(item.params),
                                "overrides": dict(item.overrides), "noise": item.noise}
        from ...offline.report import json_dump
        json_dump(path, metrics)
        return record(item, "ok", metrics)
    except ImportError as error:
        return record(item, "unavailable", {}, f"{type(error).__name__}: {error}")
    except Exception as error:          # noqa: BLE001 (one failed item must not stop the sweep)
        return record(item, "failed", {}, f"{type(error).__name__}: {error}")


def convert_bag(item: Item) -> str:
    """The run's bag (written beside, then renamed: an interrupted conversion is never reused)."""
    from .convert import write_mrclam_bag
    from .dataset import load_mrclam
    target = Path(item.bag)
    if (target / "metadata.yaml").exists():
        return "reused"
    partial = target.with_name(target.name + ".partial")
    if partial.exists():                          # left by an interrupted conversion
        shutil.rmtree(partial)
    target.parent.mkdir(parents=True, exist_ok=True)
    run = load_mrclam(item.source, item.robot, item.seconds or None, item.start)
    write_mrclam_bag(run, partial, overwrite=True, unknown_ids=item.ids == "unknown", progress=False)
    partial.rename(target)
    return "ok"


def prepared(item: Item) -> tuple:
    """(config, settings, file values, inputs, initial pose) as ``online-em-slam run`` prepares them."""
    from ...parameters.yaml_file import config_from_params, load_params
    from ...offline.runner import choose_initial_pose, read_inputs
    values: dict = {}
    for path in item.params:
        values.update(load_params(path))
    overrides = dict(item.overrides, **{"filter.seed": int(item.seed or 0)})
    if item.particles:
        overrides["filter.num_particles"] = item.particles
    config, settings = config_from_params(values, overrides)
    inputs = read_inputs(item.bag, settings)
    if not inputs.events:
        raise ValueError(f"{item.bag}: no inputs on the configured topics")
    initial = choose_initial_pose("auto", inputs, config, settings, values)
    return config, settings, values, inputs, initial


def run_method(item: Item) -> dict:
    from ...offline.runner import run_one
    config, _, values, inputs, initial = prepared(item)
    extra = {"params": " + ".join(item.params), "benchmark_method": item.method}
    return run_one(inputs, config, RUNNER_METHOD.get(item.method, item.method), initial, Path(item.out),
                   plot=item.plot, match_gate=MATCH_GATE, extra=extra, param_values=values)


def solve_batch(item: Item) -> dict:
    """The batch (offline/batch_run.py: the estimator's model solved in full, known ids) on the bag,
    written and scored as ``online-em-slam run --method batch`` does."""
    from ...offline.batch_run import batch_run
    from ...offline.runner import run_one
    config, _, values, inputs, initial = prepared(item)
    extra = {"params": " + ".join(item.params), "benchmark_method": item.method}
    return run_one(inputs, config, "batch", initial, Path(item.out), plot=item.plot, match_gate=MATCH_GATE,
                   extra=extra, param_values=values, result=batch_run(inputs, config, initial.pose))


def scored(item: Item, inputs, positions, ids) -> dict:
    """Landmark metrics of a map as the runner scores it: by id for known ids, else by position."""
    from ...offline.report import scored_landmarks
    return scored_landmarks(positions, ids, inputs, MATCH_GATE, by_id=item.ids == "known").to_dict()


def rescored(item: Item, metrics: dict) -> dict:
    """``metrics`` with the landmarks scored again from the run's landmarks.csv (confirmed ones,
    as the runner scores them) against the bag's survey: the current evaluation, same map."""
    import numpy as np
    config, _, _, inputs, _ = prepared(item)
    table = np.atleast_1d(np.genfromtxt(Path(item.out) / "landmarks.csv", delimiter=",", names=True))
    keep = np.ones(len(table), dtype=bool)
    if "n_obs" in (table.dtype.names or ()):
        keep = table["n_obs"] >= config.association.confirm_observations
    if inputs.landmarks is not None:
        metrics["landmarks"] = scored(item, inputs, np.column_stack([table["x"], table["y"]])[keep],
                                      table["id"].astype(int)[keep])
    return metrics


def record(item: Item, status: str, metrics: dict, error: str = "") -> dict:
    """What results.json keeps of a work item."""
    lm, tr, tm = metrics.get("landmarks") or {}, metrics.get("trajectory") or {}, metrics.get("timing") or {}
    row = {"key": item.key, "kind": item.kind, "run": item.run, "dataset": item.dataset, "robot": item.robot,
           "seconds": item.seconds, "start": item.start, "ids": item.ids, "method": item.method, "noise": item.noise,
           "seed": item.seed, "status": status, "error": error or None, "dir": item.out or item.bag,
           "landmark_rmse": lm.get("rmse"), "landmark_shape": lm.get("shape_error"),
           "landmark_frame": lm.get("frame_error"), "landmark_scale": lm.get("map_scale"),
           "landmark_shape_scaled": lm.get("scaled_shape_error"), "matched": lm.get("n_matched"),
           "matched_fitted": lm.get("n_matched_fitted"), "n_true": lm.get("n_true"),
           "spurious": lm.get("n_spurious"), "trajectory_rmse": tr.get("rmse"),
           "trajectory_revised_rmse": (metrics.get("trajectory_revised") or tr).get("rmse"),
           "mean_step_ms": tm.get("mean_step_ms"), "estimator_wall_s": tm.get("wall_time_s"),
           "item_wall_s": (metrics.get("benchmark") or {}).get("item_wall_s"),
           "internal_errors": (metrics.get("runner_skipped") or {}).get("internal_error", 0)}
    learned = metrics.get("noise_learned")
    if learned:
        row["noise_learned"] = {k: learned.get(k) for k in ("model", "sigma_range", "sigma_bearing",
                                                            "serial_correlation", "motion_scale")}
    return row


# --------------------------------------------------------------------------- scheduling

def run_all(items: list[Item], jobs: int, log=print) -> list[dict]:
    """Every item, each once the items it needs are done (skipped when one of them did not succeed)."""
    keys = {item.key for item in items}
    missing = {k for item in items for k in item.after} - keys
    if missing:
        raise ValueError(f"work items need unplanned items: {sorted(missing)}")
    records: dict[str, dict] = {}
    waiting = list(items)

    def finished(rec: dict) -> None:
        records[rec["key"]] = rec
        wall = rec.get("item_wall_s") if rec["status"] == "ok" else None
        log(f"[{len(records)}/{len(items)}] {rec['key']}: {rec['status']}"
            + (f" ({wall:.1f} s)" if wall is not None else "") + (f": {rec['error']}" if rec["error"] else "")
            + (f"; {rec['internal_errors']} input(s) failed inside the estimator, dropped (metrics.json "
               f"input_failures)" if rec.get("internal_errors") else ""), flush=True)

    def take_ready() -> list[Item]:
        """The waiting items whose needs are all done; those with a need that failed are skipped."""
        ready = []
        for item in list(waiting):
            needs = [records.get(k) for k in item.after]
            if any(need is None for need in needs):
                continue
            waiting.remove(item)
            bad = next((need for need in needs if need["status"] not in DONE), None)
            if bad is None:
                ready.append(item)
            else:
                finished(record(item, "skipped", {}, f"needs {bad['key']} ({bad['status']})"))
        return ready

    if jobs <= 1:
        while waiting:
            for item in take_ready():
                finished(execute(item))
        return [records[item.key] for item in items]
    for name in THREAD_VARIABLES:          # inherited by the spawned workers (numpy not yet imported there)
        os.environ[name] = "1"
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from multiprocessing import get_context
    with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
        futures: dict = {}
        while waiting or futures:
            futures.update({pool.submit(execute, item): item for item in take_ready()})
            if futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for future in done:
                    futures.pop(future)
                    finished(future.result())
    return [records[item.key] for item in items]


# --------------------------------------------------------------------------- command line

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="online-em-slam-mrclam-benchmark", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--data-dir",
                        help="directory holding MRCLAM_DatasetN directories or their archives (.zip, .tar.xz)")
    parser.add_argument("--output", help="output directory (bags/, runs/, results.json, results.md)")
    parser.add_argument("--datasets", type=int, nargs="+", default=[1, 9])
    parser.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5], choices=range(1, 6))
    parser.add_argument("--seconds", type=int, nargs="+", default=[600], help="first S seconds (0 = full length)")
    parser.add_argument("--start", type=int, default=0, metavar="S0",
                        help="every run starts S0 seconds after the robot's first odometry sample (a later "
                             "window: runs the defaults were not developed on; default 0)")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="default 0 1 2 3 4")
    parser.add_argument("--ids", nargs="+", default=["known", "unknown"], choices=("known", "unknown"))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--params", nargs="+", default=[DEFAULT_PARAMS],
                        help="parameter files, merged in order (a later file's values win; default %(default)s)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (one BLAS thread each)")
    parser.add_argument("--particles", type=int, default=None, help="override filter.num_particles")
    parser.add_argument("--rescore", action="store_true",
                        help="score the maps of existing runs again (current evaluation and survey; no re-run)")
    parser.add_argument("--compare-with", metavar="FILE",
                        help="after the run, the paired differences against another results.json (same seeds)")
    parser.add_argument("--compare", nargs=2, metavar=("A", "B"),
                        help="only print the paired differences B - A of two results.json files (with "
                             "--seeds: over those seeds only, e.g. 2 3 4 to confirm a change made on 0 1)")
    return parser


def unique(values: list) -> list:
    return list(dict.fromkeys(values))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.compare:
        return _print_comparison(*args.compare, seeds=args.seeds)
    args.seeds = args.seeds or DEFAULT_SEEDS
    if not (args.data_dir and args.output):
        parser.error("--data-dir and --output are required (unless --compare)")
    for name in ("datasets", "robots", "seconds", "seeds", "ids", "methods"):
        setattr(args, name, unique(getattr(args, name)))
    if min(args.seconds) < 0 or args.start < 0 or args.jobs < 1:
        print("online-em-slam-mrclam-benchmark: error: --seconds and --start must be >= 0 and --jobs >= 1",
              file=sys.stderr)
        return 2
    args.params = [str(Path(p).resolve()) for p in args.params]
    args.output = str(Path(args.output).resolve())
    started = time.perf_counter()
    try:
        for path in args.params:
            if not Path(path).is_file():
                raise FileNotFoundError(f"--params: {path} does not exist")
        items = plan(args)
    except FileNotFoundError as error:
        print(f"online-em-slam-mrclam-benchmark: error: {error}", file=sys.stderr)
        return 1
    Path(args.output).mkdir(parents=True, exist_ok=True)
    records = run_all(items, args.jobs)
    meta = {key: getattr(args, key) for key in ("data_dir", "datasets", "robots", "seconds", "start", "seeds", "ids",
                                                  "methods", "params", "jobs", "particles")}
    meta.update(match_gate_m=MATCH_GATE, wall_time_s=time.perf_counter() - started, cpu_count=os.cpu_count(),
                date=time.strftime("%Y-%m-%d %H:%M"))
    text = results_markdown(records, meta)
    from ...offline.report import json_dump
    json_dump(Path(args.output) / "results.json", {"meta": meta, "runs": records})
    (Path(args.output) / "results.md").write_text(text)
    print(text)
    failed = [r for r in records if r["status"] in ("failed", "skipped")]
    compared = _print_comparison(args.compare_with, str(Path(args.output) / "results.json")) if args.compare_with else 0
    return 1 if failed or compared else 0


def _print_comparison(path_a: str, path_b: str, seeds: list[int] | None = None) -> int:
    """Print the paired differences B - A (over ``seeds`` when given); 1 with a message when a file
    cannot be read."""
    try:
        print(compare_files(path_a, path_b, seeds))
    except (OSError, ValueError, KeyError) as error:
        print(f"online-em-slam-mrclam-benchmark: error: --compare: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
