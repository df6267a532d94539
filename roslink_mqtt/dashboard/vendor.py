"""The npm bundles the dashboard page loads (MQTT.js, uPlot), kept inside the package so a wheel is the whole product.

Why a copy: `roslink-mqtt dashboard` on an operator's laptop is installed with pip, from a wheel, without the
repository or npm (docs/deploy.md). So `make install` (after `npm ci`, which installs exactly what package-lock.json
pins) copies the browser builds into ``roslink_mqtt/dashboard/vendor/`` with their licences and a ``VERSIONS.json``
(package, version, sha256 of each file); the wheel's package data takes them from there, and the server serves them
from there. The copies are not committed (nothing third-party is): they are made from the lock file every time.

`make install` calls :func:`main` with the repository's node_modules.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

VENDOR_DIR = Path(__file__).resolve().parent / "vendor"
VERSIONS = VENDOR_DIR / "VERSIONS.json"
# served name → (npm package, file inside it); each package's licence travels with its files
BUNDLES = {
    "mqtt.min.js": ("mqtt", "dist/mqtt.min.js"),
    "uPlot.esm.js": ("uplot", "dist/uPlot.esm.js"),
    "uPlot.min.css": ("uplot", "dist/uPlot.min.css"),
}
LICENCES = {"mqtt": "LICENSE.md", "uplot": "LICENSE"}


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def copy_from(node_modules: Path, into: Path = VENDOR_DIR) -> dict[str, dict[str, object]]:
    """Copy the bundles and licences from an npm install into ``into``; returns what VERSIONS.json records."""
    into.mkdir(parents=True, exist_ok=True)
    record: dict[str, dict[str, object]] = {}
    for name, (package, inner) in BUNDLES.items():
        source = node_modules / package / inner
        if not source.is_file():
            raise FileNotFoundError(f"{source} is missing: run `npm ci` first (make install does)")
        shutil.copyfile(source, into / name)
        meta = json.loads((node_modules / package / "package.json").read_text())
        entry = record.setdefault(package, {"version": meta["version"], "files": {}})
        files = entry["files"]
        assert isinstance(files, dict)
        files[name] = sha256(into / name)
    for package, licence in LICENCES.items():
        shutil.copyfile(node_modules / package / licence, into / f"LICENSE-{package}")
    (into / "VERSIONS.json").write_text(json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    node_modules = Path(args[0]) if args else Path(__file__).resolve().parents[2] / "node_modules"
    try:
        record = copy_from(node_modules)
    except (OSError, KeyError, ValueError) as err:
        print(f"vendor: {err}", file=sys.stderr)
        return 1
    print("vendor: " + ", ".join(f"{package} {entry['version']}" for package, entry in sorted(record.items()))
          + f" → {VENDOR_DIR}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
