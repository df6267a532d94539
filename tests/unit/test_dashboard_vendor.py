"""The dashboard's npm bundles inside the package (roslink_mqtt/dashboard/vendor.py): copied with their licences and
a record of versions and hashes, the versions package-lock.json pins, and refused with a reason when npm has not
run. Files only, no network."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from roslink_mqtt.dashboard.vendor import BUNDLES, LICENCES, VERSIONS, copy_from, sha256

ROOT = Path(__file__).resolve().parents[2]


def _fake_node_modules(root: Path, versions: dict[str, str]) -> Path:
    for name, (package, inner) in BUNDLES.items():
        path = root / package / inner
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"/* {package} {name} */")
    for package, licence in LICENCES.items():
        (root / package / licence).write_text(f"{package} licence")
        (root / package / "package.json").write_text(json.dumps({"version": versions[package]}))
    return root


def test_the_bundles_are_copied_with_licences_versions_and_hashes(tmp_path: Path) -> None:
    node_modules = _fake_node_modules(tmp_path / "node_modules", {"mqtt": "5.16.0", "uplot": "1.6.32"})
    into = tmp_path / "vendor"
    record = copy_from(node_modules, into)
    assert record["mqtt"]["version"] == "5.16.0" and record["uplot"]["version"] == "1.6.32"
    for name in BUNDLES:
        assert (into / name).read_text().endswith(f"{name} */")
    assert (into / "LICENSE-mqtt").read_text() == "mqtt licence"
    written = json.loads((into / "VERSIONS.json").read_text())
    assert written == record and written["uplot"]["files"]["uPlot.esm.js"] == sha256(into / "uPlot.esm.js")


def test_without_npm_it_says_what_to_run(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="npm ci"):
        copy_from(tmp_path / "node_modules", tmp_path / "vendor")


@pytest.mark.skipif(not VERSIONS.is_file(), reason="no vendored bundles yet (make install makes them)")
def test_the_copies_in_the_package_are_what_the_lock_file_pins() -> None:
    lock = json.loads((ROOT / "package-lock.json").read_text())["packages"]
    record = json.loads(VERSIONS.read_text())
    for package, entry in record.items():
        assert entry["version"] == lock[f"node_modules/{package}"]["version"], package
        for name, digest in entry["files"].items():
            assert sha256(VERSIONS.parent / name) == digest, f"{name} changed since it was copied"
    # the dashboard's bundles are pinned exactly in package.json too: a new version is a deliberate change
    wanted = json.loads((ROOT / "package.json").read_text())["dependencies"]
    assert wanted["mqtt"] == record["mqtt"]["version"] and wanted["uplot"] == record["uplot"]["version"]
