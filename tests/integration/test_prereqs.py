"""tools/prereqs.sh: `make` names a missing prerequisite before installing anything (it used to fail 36 s into
`npm ci` with "npm: No such file or directory")."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.procs import ROOT

SCRIPT = ROOT / "tools" / "prereqs.sh"


def _run(*args: str, path: str = "/nonexistent", cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(["/bin/sh", str(SCRIPT), *args], cwd=cwd, env={**os.environ, "PATH": path},
                          capture_output=True, text=True, timeout=30)


def _bin(tmp_path: Path, **programs: str) -> str:
    """A PATH directory holding exactly ``programs`` (name → a /bin/sh script body)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, body in programs.items():
        exe = bin_dir / name
        exe.write_text(f"#!/bin/sh\n{body}\n")
        exe.chmod(0o755)
    return str(bin_dir)


@pytest.mark.parametrize(("programs", "named"), [
    ({}, "missing prerequisite: Node.js (node) and npm."),
    ({"node": 'exec /usr/bin/node "$@"'}, "missing prerequisite: npm."),
    ({"node": 'case "$1" in -p) echo 16;; *) echo v16.20.2;; esac', "npm": "true"},
     "missing prerequisite: Node.js >= 18 (node is v16.20.2)."),
])
def test_a_missing_or_old_node_is_named_with_how_to_get_it(tmp_path, programs, named) -> None:
    path = _bin(tmp_path, **programs)
    out = _run("node", path=path)
    assert out.returncode == 1 and named in out.stderr, out.stderr
    assert "sudo apt-get install nodejs npm" in out.stderr and "make demo runs without them" in out.stderr
    quiet = _run("node", "--quiet", path=path)  # make demo's question: is Node there? (it says the rest itself)
    assert (quiet.returncode, quiet.stderr) == (1, "")


def test_this_machines_node_and_python_pass() -> None:
    assert _run("node", path=os.environ["PATH"]).returncode == 0
    assert _run("python", sys.executable).returncode == 0


def test_a_python_outside_requires_python_is_named(tmp_path) -> None:
    """The interpreter is checked against pyproject.toml's requires-python (here one this Python does not meet)."""
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\nrequires-python = ">=3.99,<3.100"\n')
    out = _run("python", sys.executable, cwd=tmp_path)
    version = ".".join(map(str, sys.version_info[:3]))
    assert out.returncode == 1, out
    assert f"missing prerequisite: Python >=3.99,<3.100 (requires-python in pyproject.toml); {sys.executable} " \
           f"is {version}" in out.stderr, out.stderr


def test_a_missing_interpreter_is_named() -> None:
    out = _run("python", "python3.99")
    assert out.returncode == 1 and "missing prerequisite: python3.99" in out.stderr, out.stderr


def test_the_venv_python_is_the_one_the_ros_wheels_are_built_for(tmp_path) -> None:
    """The core takes 3.10..3.13, but the venv `make` builds holds the bridge: its ROS wheels' Python is checked."""
    (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\nrequires-python = ">=3.10"\n'
                                             "[project.optional-dependencies]\n"
                                             "bridge = [\"ros-jazzy-rclpy==7.1.6; python_version == '3.99'\"]\n")
    out = _run("python", sys.executable, cwd=tmp_path)
    assert out.returncode == 1, out
    assert "missing prerequisite: Python ==3.99 (the bridge's ROS 2 wheels in pyproject.toml)" in out.stderr, \
        out.stderr
