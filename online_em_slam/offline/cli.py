"""Offline runner: a bag straight into an estimator (no DDS), deterministic for a seed.

    online-em-slam run BAG --params FILE --output DIR [--method online_em|ekf_slam|fastslam2|marginal_slam|batch]
                       [--fleet]
                       [--seed S] [--particles N] [--initial-pose auto|ground_truth|gps|params|X,Y,YAW]
                       [--match-gate M] [--align] [--no-plot]
    online-em-slam compare BAG --params FILE --output DIR [--methods ...] [--fleet] [--seed S] ...

``run`` reads the bag (rosbags, no rclpy) and feeds the estimator through the
node's own input path (:mod:`online_em_slam.offline.runner`, with
:mod:`online_em_slam.pipeline`: stamp checks, the (stamp, tie rule) ordered merge of
the streams, the feeder), so the estimator sees the identical sequence of
inputs as the node: the control topic ->
``add_control`` (``motion_source: control``) or the odometry topic ->
``add_odometry`` (``motion_source: odom``), the observation topic (PointCloud2
with fields range, bearing and optional id, range_std, bearing_std) ->
``add_observations``.  Topic names and every setting come from the node's
parameter file (``--params``), read with :mod:`online_em_slam.parameters.yaml_file`.
Empty observation clouds and observations before the first motion input are not
fed (counted under ``runner_skipped`` in metrics.json, with every input the path
or the node's cloud and quaternion checks refused, by reason).  An input that raises
inside the estimator is dropped with the estimate kept as before it (the node's
rule), counted as ``internal_error``, its message kept in ``input_failures`` (the
first five) and reported on stderr after the summary line.  A bag or parameter
file that cannot be used (not a bag, unreadable, a topic of another message type
than the node reads, no motion input, no observations, a refused value) ends the
run with one line ``online-em-slam: error: FILE: what is wrong`` and exit status 1.

Initial pose (``--initial-pose``, default ``auto``): the ``initial_pose.*`` keys
of the params file when it sets any; otherwise, when the bag has
``/ground_truth/pose`` (motion capture, MRCLAM), the ground-truth pose at the
first input; otherwise, when the bag has ``/ground_truth/position`` (a GPS measuring the sensor point, in the map frame),
from GPS: the sensor point at the first fix, the heading fitted to the first
10 m of GPS track (using /odom for the shape of the track when the bag has it;
see :func:`online_em_slam.offline.evaluation.initial_pose_from_gps`); else (0, 0, 0).
No trajectory alignment is applied afterwards (``--align`` additionally reports
the error after a rigid alignment).  An initial pose not taken from the ground truth
(params, X,Y,YAW) that lies farther than the match gate or 10 deg from the ground
truth's start puts the estimate in another frame: it is then scored after the motion
that carries its start pose onto the ground truth's, and the summary and
metrics.json's ``frame`` say so (:mod:`online_em_slam.offline.frames`).

Outputs in DIR: ``trajectory.csv`` (t,x,y,yaw: the base pose after each
observation message), ``landmarks.csv`` (id,x,y,cov_xx,cov_xy,cov_yy,n_obs: the
whole map, as the node publishes it), ``metrics.json`` (timing, real-time factor,
map size, drops; landmark metrics against ``/ground_truth/landmarks`` and
trajectory metrics of the sensor point against ``/ground_truth/position`` when
the bag has them), ``noise.yaml`` (online EM: the parameter file with the noise
it learned; :func:`online_em_slam.offline.report.write_noise_params`) and ``map.png``.  Landmark metrics count the landmarks seen at
least ``association.confirm_observations`` times (the confirmed ones).

``run --fleet`` takes a fleet bag (``online-em-slam-convert mrclam OUT --all-robots``: each
robot's topics under ``/robotK``) and runs every robot into one online EM fleet
(:mod:`online_em_slam.offline.fleet_runner`): DIR/landmarks.csv (the joint map),
DIR/robotK/trajectory.csv, metrics.json with the joint map's landmark metrics and each
robot's trajectory metrics under ``robots``.

``compare`` runs several methods on the same bag (DIR/<method>/ as ``run``) and
writes ``comparison.md`` and ``comparison.json``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..core.config import SlamConfig
from .evaluation import DEFAULT_MATCH_GATE
from ..parameters.specs import ParameterError
from ..parameters.yaml_file import ParamFileError, config_from_params, load_params
from .report import comparison_markdown, comparison_row, failure_warning, json_dump, summary_line
from .runner import METHODS, choose_initial_pose, read_inputs, run_one


def prepare(args) -> tuple:
    """(config, settings, file values, inputs, initial pose) from the common arguments."""
    config, settings, file_values = read_parameters(args)
    inputs = read_inputs(args.bag, settings)
    if not inputs.events:
        raise ValueError(f"{args.bag}: no inputs on the configured topics "
                         f"({settings.control_topic if settings.motion_source == 'control' else settings.odom_topic}, "
                         f"{settings.observations_topic})")
    initial = choose_initial_pose(args.initial_pose, inputs, config, settings, file_values)
    return config, settings, file_values, inputs, initial


def read_parameters(args) -> tuple:
    """(config, settings, file values) from ``--params`` (merged in order), ``--seed`` and ``--particles``."""
    per_file, file_values = [], {}
    for path in args.params:
        try:
            per_file.append((path, load_params(path)))
        except OSError as error:            # a directory, unreadable: load_params lets these through
            raise ParamFileError(f"{path}: cannot read the parameter file: {error.strerror or error}") from None
        file_values.update(per_file[-1][1])
    overrides = {}
    if args.seed is not None:
        overrides["filter.seed"] = int(args.seed)
    if args.particles is not None:
        overrides["filter.num_particles"] = int(args.particles)
    try:
        config, settings = config_from_params(file_values, overrides)
    except ParameterError as error:
        raise ParameterError(f"{_culprit(per_file)}{error}") from None
    return config, settings, file_values


def _culprit(per_file) -> str:
    """"FILE: " for the last parameter file whose values alone are refused (else "")."""
    for path, values in reversed(per_file):
        try:
            config_from_params(values)
        except ParameterError:
            return f"{path}: "
    return ""


def _run_options(args, file_values: dict) -> dict:
    return {"plot": not args.no_plot, "match_gate": args.match_gate, "align": args.align,
            "extra": {"params": _params_label(args)}, "param_values": file_values}


def _params_label(args) -> str:
    """The parameter files as one string for reports: "a.yaml", or "a.yaml + b.yaml"."""
    return " + ".join(str(path) for path in args.params)


def _made_otherwise(method: str, inputs, config, initial):
    """The batch's run (offline/batch_run.py), which no estimator makes; None for an estimator."""
    if method != "batch":
        return None
    from .batch_run import batch_run
    return batch_run(inputs, config, initial.pose)


def _warn_failures(metrics: dict) -> None:
    warning = failure_warning(metrics)
    if warning:
        print(warning, file=sys.stderr, flush=True)


def cmd_run(args) -> int:
    if args.fleet:
        if args.method != "online_em":
            raise ValueError(f"--fleet runs online EM's fleet mode; --method {args.method} has none")
        from .fleet_runner import cmd_run_fleet
        config, settings, file_values = read_parameters(args)
        return cmd_run_fleet(args, config, settings, file_values, {"params": _params_label(args)})
    config, _, file_values, inputs, initial = prepare(args)
    metrics = run_one(inputs, config, args.method, initial, Path(args.output), **_run_options(args, file_values),
                      result=_made_otherwise(args.method, inputs, config, initial))
    print(summary_line(metrics))
    _warn_failures(metrics)
    if metrics.get("frame") and metrics["frame"]["same_frame"] is not True:
        print(f"note: {metrics['frame']['note']}")
    print(f"wrote {args.output}/trajectory.csv, landmarks.csv, metrics.json" + ("" if args.no_plot else ", map.png")
          + (", noise.yaml" if "noise_learned" in metrics else ""))
    return 0


def cmd_compare(args) -> int:
    if args.fleet:
        from .fleet_compare import cmd_compare_fleet
        config, settings, file_values = read_parameters(args)
        return cmd_compare_fleet(args, config, settings, file_values, {"params": _params_label(args)})
    config, _, file_values, inputs, initial = prepare(args)
    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    rows = []
    for method in args.methods:
        cfg = SlamConfig.from_dict(config.to_dict())      # fresh copy per method
        metrics = run_one(inputs, cfg, method, initial, output / method, **_run_options(args, file_values),
                          result=_made_otherwise(method, inputs, cfg, initial))
        print(summary_line(metrics), flush=True)
        _warn_failures(metrics)
        rows.append(comparison_row(metrics))
    json_dump(output / "comparison.json", {"bag": str(args.bag), "params": _params_label(args),
                                           "seed": config.filter.seed, "num_particles": config.filter.num_particles,
                                           "initial_pose": initial.to_dict(), "methods": rows})
    (output / "comparison.md").write_text(comparison_markdown(rows, args.bag, _params_label(args), config.filter.seed,
                                                              config.filter.num_particles))
    print((output / "comparison.md").read_text())
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="online-em-slam",
                                     description="Offline SLAM runs on ROS 2 bags (no DDS) and their evaluation.")
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("bag", help="ROS 2 bag directory (mcap or sqlite3)")
        p.add_argument("--params", required=True, action="append",
                       help="node parameter file (ROS 2 params YAML); given more than once the files merge "
                            "in order, a later file's values winning (as several --params-file to a node)")
        p.add_argument("--output", required=True, help="output directory")
        p.add_argument("--seed", type=int, default=None, help="random seed (overrides filter.seed)")
        p.add_argument("--particles", type=int, default=None, help="number of particles (overrides filter.num_particles)")
        p.add_argument("--initial-pose", default="auto", metavar="auto|ground_truth|gps|params|X,Y,YAW",
                       help="initial base pose (default auto: params file if it sets initial_pose.*, else the "
                            "bag's /ground_truth/pose, else GPS)")
        p.add_argument("--match-gate", type=float, default=DEFAULT_MATCH_GATE,
                       help="landmark matching gate (m) for the metrics")
        p.add_argument("--align", action="store_true",
                       help="also report the trajectory error after a rigid 2-D alignment")
        p.add_argument("--no-plot", action="store_true", help="do not write map.png")

    run = sub.add_parser("run", help="run one method on a bag")
    common(run)
    run.add_argument("--method", choices=METHODS + ("batch",), default="online_em",
                     help="an estimator, or batch: the estimator's model solved in full by GTSAM (known ids; "
                          "docs/METHOD.md, \"The batch reference\")")
    run.add_argument("--fleet", action="store_true",
                     help="a fleet bag (robots under /robot1, /robot2, ...): every robot into one online EM "
                          "fleet, one joint map (online_em_slam.offline.fleet_runner)")
    run.set_defaults(func=cmd_run)
    compare = sub.add_parser("compare", help="run several methods on a bag and tabulate them")
    common(compare)
    compare.add_argument("--methods", nargs="+", choices=METHODS + ("batch",), default=list(METHODS))
    compare.add_argument("--fleet", action="store_true",
                         help="a fleet bag: online EM's fleet run and the GTSAM batch over every robot "
                              "(file and learned noise) (online_em_slam.offline.fleet_compare)")
    compare.set_defaults(func=cmd_compare)
    from .evaluate_recording import add_parser as add_evaluate     # recorded node runs
    add_evaluate(sub)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as error:
        print(f"online-em-slam: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
