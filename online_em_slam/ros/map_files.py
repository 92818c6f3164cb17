"""Map files by name: the services ``~/save_map`` and ``~/load_map``.

Each call names its file, as slam_toolbox's serialize/deserialize services do.  No
custom interface can be built for this package (no rosidl step), so the file name
travels in the one standard service of the installed interfaces that takes named,
typed arguments and answers each with a success flag and a reason:
``rcl_interfaces/srv/SetParameters``, with one string argument named ``file``::

    ros2 service call /online_em_slam/save_map rcl_interfaces/srv/SetParameters \\
        "{parameters: [{name: file, value: {type: 4, string_value: run1}}]}"

The answer is one ``SetParametersResult``: ``successful`` and ``reason`` (what was saved
or loaded, or why not).  No argument means the ``map_file`` parameter.  A name without
``.npz`` gets it.  Every name is resolved inside the map directory (``map_directory``,
else the directory of ``map_file``): '..', absolute paths elsewhere and symlinks out of
it are refused.  The Trigger services ``~/save_map_file`` and ``~/load_map_file`` save
and load ``map_file`` for callers of the former Trigger interface.
"""
from __future__ import annotations

import os

from rcl_interfaces.msg import ParameterType, SetParametersResult
from rcl_interfaces.srv import SetParameters
from std_srvs.srv import Trigger

from ..core.mapping.mapfile import confined_path, map_file_path

FILE_ARGUMENT = "file"
MAP_SUFFIX = ".npz"


class MapArgumentError(ValueError):
    """A save/load request whose arguments are not one string named ``file``."""


def requested_file(parameters) -> str | None:
    """The file name of a SetParameters request (rcl_interfaces/msg/Parameter list); None: map_file.

    MapArgumentError for anything but at most one string argument named ``file``.
    """
    if not parameters:
        return None
    names = [p.name for p in parameters]
    if len(parameters) > 1:
        raise MapArgumentError(f"one argument expected, got {len(parameters)} ({', '.join(names)}); "
                               f"give the map file as a string argument named '{FILE_ARGUMENT}'")
    argument = parameters[0]
    if argument.name != FILE_ARGUMENT:
        raise MapArgumentError(f"unknown argument '{argument.name}': give the map file as a string "
                               f"argument named '{FILE_ARGUMENT}'")
    if argument.value.type != ParameterType.PARAMETER_STRING:
        raise MapArgumentError(f"argument '{FILE_ARGUMENT}' must be a string (type: 4), "
                               f"got type {argument.value.type}")
    return argument.value.string_value


def with_suffix(file_name: str) -> str:
    """``file_name`` with ``.npz`` appended unless it ends with it (blank names stay blank)."""
    name = file_name.strip()
    return name if not name or name.endswith(MAP_SUFFIX) else name + MAP_SUFFIX


class MapFiles:
    """The map-file services of the node (``node``: OnlineEmSlamNode; they act under its lock)."""

    def __init__(self, node) -> None:
        self.node = node
        node.create_service(SetParameters, "~/save_map", self._save_named)
        node.create_service(SetParameters, "~/load_map", self._load_named)
        node.create_service(Trigger, "~/save_map_file", self._save_trigger)
        node.create_service(Trigger, "~/load_map_file", self._load_trigger)

    # ------------------------------------------------------------------ paths
    def directory(self) -> str:
        s = self.node.settings
        return map_file_path(s.map_file, s.map_directory)[1]

    def path(self, file_name: str | None) -> str:
        """The file's absolute path inside the map directory (MapFileError if it escapes)."""
        s = self.node.settings
        name = map_file_path(s.map_file, s.map_directory)[0] if file_name is None else with_suffix(file_name)
        return confined_path(name, self.directory())

    # ------------------------------------------------------------------ actions
    def save(self, file_name: str | None = None) -> tuple[bool, str]:
        """Save the map to ``file_name`` (None: map_file): (success, message)."""
        node = self.node
        with node.lock:
            try:
                path = self.path(file_name)
                # Only the map directory itself (never its parents) and directories inside
                # it are created; the path is resolved again once they exist.
                root = os.path.realpath(self.directory())
                if not os.path.isdir(root):
                    os.mkdir(root)
                os.makedirs(os.path.dirname(path), exist_ok=True)
                path = self.path(file_name)
                node.slam.save_map(path)    # validated, fsynced temporary file + rename
                return True, f"saved {len(node.slam.landmarks())} landmarks to {path}"
            except Exception as error:  # noqa: BLE001 - a failed save must never stop the node
                return False, f"could not save map: {error}"

    def load(self, file_name: str | None = None) -> tuple[bool, str]:
        """Load ``file_name`` (None: map_file) into the estimator: (success, message)."""
        node = self.node
        with node.lock:
            try:
                path = self.path(file_name)
                node.slam.load_map(path)    # validated completely first; unchanged on failure
            except Exception as error:  # noqa: BLE001
                return False, f"could not load map: {error}"
            node.inputs.pipeline.checkpoint()
            node.outputs.map_dirty = True
            node.outputs.path.clear()
            if node.fleet_mode:          # every robot's filter restarted on the loaded map
                node.inputs.clear_paths()
        node.outputs.publish_map()
        return True, f"loaded {len(node.slam.landmarks())} landmarks from {path}"

    # ------------------------------------------------------------------ services
    def _named(self, action, verb: str, request, response):
        try:
            ok, message = action(requested_file(request.parameters))
        except MapArgumentError as error:
            ok, message = False, f"could not {verb} map: {error}"
        self.node.log_result(ok, message)
        response.results = [SetParametersResult(successful=ok, reason=message)]
        return response

    def _save_named(self, request, response):
        return self._named(self.save, "save", request, response)

    def _load_named(self, request, response):
        return self._named(self.load, "load", request, response)

    def _save_trigger(self, request, response):
        response.success, response.message = self.save()
        self.node.log_result(response.success, response.message)
        return response

    def _load_trigger(self, request, response):
        response.success, response.message = self.load()
        self.node.log_result(response.success, response.message)
        return response
