"""An environment in which ``rclpy`` and ``amqtt`` cannot be imported, to prove the SDK needs neither.

A ``sitecustomize.py`` on PYTHONPATH installs a meta-path finder that refuses
those packages, so every child process started with :func:`no_ros_env` runs
as on a client machine with only the core install.
"""

from __future__ import annotations

import os
from pathlib import Path

BLOCKED = ("rclpy", "amqtt")

SITECUSTOMIZE = f'''
import sys

class _BlockServerPackages:
    """Installed by tests/support/no_ros.py: the SDK must work without these."""
    blocked = {BLOCKED!r}

    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in self.blocked:
            raise ModuleNotFoundError(f"No module named {{name!r}} (blocked: core install only)", name=name)
        return None

sys.meta_path.insert(0, _BlockServerPackages())
'''


def no_ros_env(workdir: Path, base: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``base`` (default os.environ) whose Python processes cannot import rclpy or amqtt."""
    site = workdir / "no_ros_site"
    site.mkdir(parents=True, exist_ok=True)
    (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = dict(os.environ if base is None else base)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), env.get("PYTHONPATH", "")) if p)
    return env
