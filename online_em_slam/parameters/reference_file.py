"""config/online_em_slam.yaml, generated from the parameter specs (parameters/specs.py): one source.

    python -m online_em_slam.parameters.reference_file > config/online_em_slam.yaml

Every key, default, description, range and read-only flag comes from the specs
that also build the ROS parameter descriptors and the offline params-file
reader; the core ones are derived from the field metadata of core/config.py,
which SlamConfig.validate checks (a range shown "(0, 100]" excludes 0).
test/test_params_file.py checks the committed file is this output, so they can
never disagree.
"""
from __future__ import annotations

import sys
import textwrap

from .specs import NODE_SPECS, ParamSpec, core_specs, range_text

HEADER = """\
# Parameters of online_em_slam_node (ros2 run online_em_slam online_em_slam_node
#   --ros-args --params-file config/online_em_slam.yaml).
# Values shown are the defaults. Units are SI (m, s, rad). Write floats with a decimal
# point (1.0, not 1): ROS 2 refuses an integer for a double parameter.
# Core settings (motion.*, sensor.*, noise.*, filter.*, em.*, association.*) changed at run
# time take effect at the next reset (~/reset); out-of-range values are refused.
# Generated from the core's field metadata (online_em_slam/core/config.py) and the node specs
# (online_em_slam/parameters/specs.py): python -m online_em_slam.parameters.reference_file
/**:
  ros__parameters:
"""
# Node sections open at these keys; core sections at each new prefix.
NODE_SECTIONS = {"map_frame": "frames, TF and publishing", "motion_source": "inputs",
                 "map_file": "map file and initial pose", "warn_throttle_period": "logging and display"}
SECTION_NOTES = {
    "noise_learning": ('noise learned online (docs/METHOD.md "Noise learned online"): the noise.* values '
                       "above and the motion noise are starting points; EM estimates them from the data and "
                       "uses them once warmed up. /diagnostics shows them (noise_learned.*); `online-em-slam "
                       "run` writes DIR/noise.yaml, a parameter file with the learned values."),
}
WIDTH = 100


def value_text(value) -> str:
    """YAML for a default: strings quoted, floats always with a decimal point."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return repr(value)          # shortest text that reads back to the same double
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(value_text(v) for v in value) + "]"
    return str(value)


def comment(spec: ParamSpec) -> str:
    text = spec.description
    interval = range_text(spec)
    if interval is not None:
        text += f" {'Each entry in' if isinstance(spec.default, list) else 'Range'} {interval}."
    if spec.read_only:
        text += " Read-only (set at start-up)."
    return textwrap.fill(text, WIDTH, initial_indent="    # ", subsequent_indent="    # ")


def section_header(spec: ParamSpec, previous: ParamSpec | None) -> str | None:
    if spec.name in NODE_SECTIONS:
        title = NODE_SECTIONS[spec.name]
    elif "." in spec.name and spec.name.split(".")[0] in SECTION_NOTES | _core_sections():
        prefix = spec.name.split(".")[0]
        if previous is not None and previous.name.split(".")[0] == prefix:
            return None
        title = "core: " + SECTION_NOTES.get(prefix, prefix)
    else:
        return None
    return textwrap.fill(f"---- {title}", WIDTH, initial_indent="    # ", subsequent_indent="    # ")


def _core_sections() -> dict:
    return {spec.name.split(".")[0]: None for spec in core_specs()}


def generate() -> str:
    lines = [HEADER.rstrip("\n")]
    previous = None
    for spec in list(NODE_SPECS) + core_specs():
        header = section_header(spec, previous)
        if header:
            lines += ["", header]
        lines += [comment(spec), f"    {spec.name}: {value_text(spec.default)}"]
        previous = spec
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.stdout.write(generate())
