"""ROS 2 parameter files read without ROS (for the offline runner, demo and tests).

A ROS 2 params YAML maps node names to ``ros__parameters``::

    /**:                       # every node
      ros__parameters:
        motion_source: "control"
        motion:                # nested maps are flattened: motion.model
          model: "acfr"
    /**/online_em_slam:        # or /online_em_slam, /ns/online_em_slam, online_em_slam
      ros__parameters:
        filter.num_particles: 100

:func:`load_params` merges the sections that apply to ``node_name`` (wildcard
sections first, then the node's own, in file order) and flattens nested maps to
the node's dotted parameter names.  :func:`config_from_params` turns the result
into ``(SlamConfig, NodeSettings)`` through :func:`online_em_slam.parameters.specs.build`,
exactly as the node does with its declared parameters (the defaults fill in the
keys the file does not set; a bad value raises ``ParameterError``).  Defaults,
ranges and descriptions are the node's parameter specs, whose core part is
derived from the field metadata of :mod:`online_em_slam.core.config`.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import yaml

from .specs import NodeSettings, build

NODE_NAME = "online_em_slam"
PARAMS_KEY = "ros__parameters"

__all__ = ["NODE_NAME", "NodeSettings", "load_params", "flatten", "config_from_params", "ParamFileError"]


class ParamFileError(ValueError):
    """The file is not a ROS 2 parameter file, or holds nothing for the node."""


def flatten(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested maps -> dotted names ({'motion': {'model': 'acfr'}} -> {'motion.model': 'acfr'})."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, Mapping):
            out.update(flatten(value, name))
        else:
            out[name] = value
    return out


def _section_matches(key: str, node_name: str) -> int:
    """0 = no match, 1 = wildcard section, 2 = the node's own section."""
    key = str(key).strip()
    if key in ("/**", "**"):
        return 1
    parts = [p for p in key.split("/") if p]
    if not parts:
        return 0
    if parts[-1] == node_name:
        # /online_em_slam, online_em_slam, /**/online_em_slam, /ns/online_em_slam
        return 2
    if parts[-1] in ("**", "*"):
        return 1
    return 0


def params_from_document(document: Mapping[str, Any], node_name: str = NODE_NAME,
                         source: str = "parameters") -> dict[str, Any]:
    """Flat parameters for ``node_name`` from a parsed params YAML document."""
    if not isinstance(document, Mapping):
        raise ParamFileError(f"{source}: expected a map of node names at the top level")
    wildcard: dict[str, Any] = {}
    own: dict[str, Any] = {}
    matched = False
    for key, section in document.items():
        rank = _section_matches(key, node_name)
        if not rank:
            continue
        if not isinstance(section, Mapping) or PARAMS_KEY not in section:
            raise ParamFileError(f"{source}: section {key!r} has no {PARAMS_KEY!r}")
        matched = True
        values = section[PARAMS_KEY] or {}
        if not isinstance(values, Mapping):
            raise ParamFileError(f"{source}: {key}.{PARAMS_KEY} must be a map")
        (wildcard if rank == 1 else own).update(flatten(values))
    if not matched:
        raise ParamFileError(f"{source}: no '/**', '/**/{node_name}' or '{node_name}' section "
                             f"with {PARAMS_KEY!r}")
    merged = dict(wildcard)
    merged.update(own)
    return merged


def load_params(path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Flat ``{dotted name: value}`` of ``node_name`` from the ROS 2 params YAML at ``path``."""
    path = Path(os.path.expanduser(os.fspath(path)))
    try:
        with open(path, encoding="utf-8") as handle:
            document = yaml.safe_load(handle)
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        where = getattr(error, "problem_mark", None)
        line = f" (line {where.line + 1})" if where is not None else ""
        raise ParamFileError(f"{path}: not a YAML parameter file{line}: "
                             f"{getattr(error, 'problem', None) or error}") from None
    if document is None:
        return {}
    return params_from_document(document, node_name, source=str(path))


def config_from_params(path_or_dict=None, overrides: Mapping[str, Any] | None = None,
                       node_name: str = NODE_NAME):
    """``(SlamConfig, NodeSettings)`` from a params file, a parsed params document or a
    (flat or nested) dict of parameters; ``overrides`` (flat names) are applied last.

    Raises ``online_em_slam.parameters.specs.ParameterError`` for bad values and
    :class:`ParamFileError` for a malformed file.
    """
    if path_or_dict is None:
        values: dict[str, Any] = {}
    elif isinstance(path_or_dict, Mapping):
        if any(isinstance(v, Mapping) and PARAMS_KEY in v for v in path_or_dict.values()):
            values = params_from_document(path_or_dict, node_name)
        else:
            values = flatten(path_or_dict)
    else:
        values = load_params(path_or_dict, node_name)
    values = dict(values)
    values.update(overrides or {})
    return build(values)
