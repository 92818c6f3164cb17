"""cmake + ninja: generate tf2_msgs (TFMessage only) with rosidl and install it into a prefix.

The sources (``source/``: package.xml, CMakeLists.txt, msg/TFMessage.msg, the real
message definition, so the real type hash RIHS01_e369d0f0...) are package data of
online_em_slam, so an installed package builds from its own copy.  The result is
a ROS prefix inside the Python environment: the Python package in site-packages,
``lib*.so`` in ``PREFIX/lib`` (on the LD_LIBRARY_PATH the wheels' start-up re-exec
sets), ``share/tf2_msgs`` for the ament index.

The wheels' exported CMake targets name the wheel builder's Python and numpy
include directories (``/opt/python/...``); :func:`fix_exported_paths` rewrites
them to this interpreter's in the prefix's ``share/*/cmake`` files, or CMake
refuses the imported targets.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

#: The tf2_msgs source package (TFMessage only), shipped as package data.
SOURCE_DIR = Path(__file__).resolve().parent / "source"
SOURCE_FILES = ("package.xml", "CMakeLists.txt", "msg/TFMessage.msg")
#: The pip requirements of the build (also the tail of setup.py's "ros" extra).
REQUIREMENTS_FILE = SOURCE_DIR / "requirements.txt"
#: Paths of the wheel build machine found in the wheels' exported CMake targets.
BUILDER_PATHS = (
    (re.compile(r"/opt/python/cp\d+-cp\d+/lib/python[\d.]+/site-packages/numpy/_core/include"), "numpy"),
    (re.compile(r"/opt/python/cp\d+-cp\d+/include/python[\d.]+"), "python"),
)


class BuildError(RuntimeError):
    """The build cannot start or failed; the message is one line saying why (and the fix)."""


def requirements(path: Path = REQUIREMENTS_FILE) -> list[str]:
    """The build's pip requirement lines (comments and blank lines left out)."""
    lines = (line.split("#", 1)[0].strip() for line in Path(path).read_text().splitlines())
    return [line for line in lines if line]


def tool_path(prefix: Path) -> str:
    """PATH with the prefix's bin first (pip's cmake and ninja live there)."""
    return f"{Path(prefix) / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"


def missing(prefix: Path, source: Path = SOURCE_DIR) -> str | None:
    """Why the build cannot start here (one line with the fix), or None."""
    for name in SOURCE_FILES:
        if not (Path(source) / name).is_file():
            return f"{Path(source) / name} is missing (a broken online_em_slam install: reinstall it)"
    path = tool_path(prefix)
    for tool, apt in (("cmake", "cmake"), ("ninja", "ninja-build")):
        if shutil.which(tool, path=path) is None:
            return f"{tool} not found (pip install \"online_em_slam[ros]\", or apt-get install {apt})"
    for language, names in (("C", ("CC", "cc", "gcc", "clang")), ("C++", ("CXX", "c++", "g++", "clang++"))):
        candidates = (os.environ.get(names[0], "").split()[:1] or []) + list(names[1:])
        if not any(shutil.which(cc, path=path) for cc in candidates):
            return f"no {language} compiler found (apt-get install build-essential, or set {names[0]})"
    if not (Path(prefix) / "share" / "rosidl_default_generators").is_dir():
        return (f"the rosidl generators are not installed in {prefix} "
                "(pip install \"online_em_slam[ros]\", or online-em-slam-tf2-msgs build --install-requirements)")
    if not os.access(prefix, os.W_OK):
        return f"{prefix} is not writable"
    return None


def write_sources(workdir: Path, source: Path = SOURCE_DIR) -> Path:
    """Copy the tf2_msgs package sources (TFMessage only) to ``workdir/tf2_msgs``."""
    src = Path(workdir) / "tf2_msgs"
    for name in SOURCE_FILES:
        if not (Path(source) / name).is_file():
            raise BuildError(f"{Path(source) / name} is missing (a broken online_em_slam install: reinstall it)")
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(Path(source) / name, src / name)
    return src


def fix_exported_paths(prefix: Path) -> int:
    """Rewrite the wheel builder's include directories in ``prefix/share/*/cmake``; returns files changed."""
    local = {"python": sysconfig.get_paths()["include"]}
    try:
        import numpy  # noqa: PLC0415 (optional: only its include directory)
        local["numpy"] = numpy.get_include()
    except ImportError:
        pass
    changed = 0
    for path in Path(prefix, "share").glob("*/cmake/*.cmake"):
        text = original = path.read_text(errors="surrogateescape")
        for pattern, key in BUILDER_PATHS:
            if key in local:
                text = pattern.sub(local[key], text)
        if text != original:
            path.write_text(text, errors="surrogateescape")
            changed += 1
    return changed


def install_requirements(output, timeout: float = 900.0) -> None:
    """pip install the build requirements into this interpreter's environment."""
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "-r", str(REQUIREMENTS_FILE)],
                   stdout=output, stderr=subprocess.STDOUT, check=True, timeout=timeout)


def build(prefix: Path, workdir: Path, log=print, output=None, timeout: float = 900.0) -> None:
    """Configure, build and install tf2_msgs into ``prefix``.

    Raises BuildError (cannot start: the reason), CalledProcessError or TimeoutExpired;
    ``output``: a file for cmake's and ninja's output (default: inherited)."""
    prefix = Path(prefix)
    reason = missing(prefix)
    if reason:
        raise BuildError(reason)
    src = write_sources(workdir)
    log(f"tf2_msgs: fixed the builder's include paths in {fix_exported_paths(prefix)} CMake files")
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), CMAKE_PREFIX_PATH=str(prefix), PATH=tool_path(prefix))
    build_dir = Path(workdir) / "build"
    shutil.rmtree(build_dir, ignore_errors=True)      # a fresh configure: no cache from a failed attempt
    run = dict(env=env, check=True, timeout=timeout, stdout=output, stderr=subprocess.STDOUT if output else None)
    subprocess.run(["cmake", "-S", str(src), "-B", str(build_dir), "-G", "Ninja", "-DBUILD_TESTING=OFF",
                    f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DPython3_EXECUTABLE={sys.executable}"], **run)
    subprocess.run(["ninja", "-C", str(build_dir), "install"], **run)
