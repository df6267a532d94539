"""``roslink-mqtt acl export --format mosquitto``: files, permissions, same rules as the embedded broker."""

from __future__ import annotations

import dataclasses
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from roslink_mqtt.broker.acl import FleetAcl
from roslink_mqtt.broker.export import ExportError, export_mosquitto, passwd_text
from roslink_mqtt.cli.main import main as cli
from roslink_mqtt.config import load_fleet, verify_password
from tests.support.procs import CONFIG, DEMO_PASSWORDS


def test_cli_writes_passwd_acl_and_conf(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mosq"
    assert cli(["acl", "export", "--format", "mosquitto", "--out", str(out), "--config", str(CONFIG)]) == 0
    assert "mosquitto -c" in capsys.readouterr().out
    fleet = load_fleet(CONFIG)

    passwd = dict(line.split(":", 1) for line in (out / "passwd").read_text().splitlines())
    assert set(passwd) == set(DEMO_PASSWORDS)
    for login, password in DEMO_PASSWORDS.items():
        assert passwd[login] == fleet.password_hash(login)  # straight from robots.yaml
        assert verify_password(password, passwd[login])

    acl = (out / "acl").read_text()
    blocks: dict[str, list[str]] = {}
    current = None
    for line in acl.splitlines():
        if line.startswith("user "):
            current = line[5:]
            blocks[current] = []
        elif line.startswith("topic "):
            assert current is not None, "topic line outside a user block would apply to every client"
            blocks[current].append(line)
    rules = FleetAcl(fleet)
    assert set(blocks) == set(rules.logins)
    for login, lines in blocks.items():
        assert lines == [f"topic {e.access.mosquitto} {e.pattern}" for e in rules.entries(login)]

    conf = (out / "mosquitto.conf").read_text().splitlines()
    assert "listener 1883 127.0.0.1" in conf
    assert "listener 8083 127.0.0.1" in conf and "protocol websockets" in conf
    assert "allow_anonymous false" in conf
    assert f"password_file {(out / 'passwd').resolve()}" in conf
    assert f"acl_file {(out / 'acl').resolve()}" in conf
    for name in ("passwd", "acl", "mosquitto.conf"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o600


def test_bad_config_is_reported_with_file_and_line(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "robots.yaml"
    bad.write_text(CONFIG.read_text().replace("system_id: 1", "system_id: one"))
    assert cli(["acl", "export", "--out", str(tmp_path / "o"), "--config", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:" in err and "system_id" in err


def test_logins_mosquitto_cannot_express_are_refused(tmp_path: Path) -> None:
    fleet = load_fleet(CONFIG)
    users = {**fleet.users, "ev:il": dataclasses.replace(fleet.users["bob"], name="ev:il")}
    with pytest.raises(ExportError, match="ev:il"):
        passwd_text(dataclasses.replace(fleet, users=users))
    with pytest.raises(ExportError):
        export_mosquitto(dataclasses.replace(fleet, users=users), tmp_path)


def test_export_works_without_amqtt(tmp_path: Path) -> None:
    """A client install has no amqtt: `roslink-mqtt acl export` must not need it."""
    code = ("import sys; sys.modules['amqtt'] = None\n"  # any 'import amqtt' now raises ImportError
            "from roslink_mqtt.cli.main import main\n"
            f"sys.exit(main(['acl', 'export', '--out', {str(tmp_path)!r}, '--config', {str(CONFIG)!r}]))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "acl").exists()


def test_committed_example_is_what_export_writes(tmp_path: Path, monkeypatch) -> None:
    """broker/example-export/ shows users the export of the demo fleet; it must not drift from the code."""
    example = CONFIG.parents[1] / "broker" / "example-export"
    out = tmp_path / "roslink"
    monkeypatch.chdir(CONFIG.parents[1])  # the header names the fleet file as given: config/robots.yaml
    assert cli(["acl", "export", "--format", "mosquitto", "--out", str(out), "--config", "config/robots.yaml"]) == 0
    for name in ("passwd", "acl", "mosquitto.conf"):
        fresh = (out / name).read_text().replace(str(out.resolve()), "/etc/mosquitto/roslink")
        assert (example / name).read_text() == fresh, (
            f"broker/example-export/{name} is stale: export the demo fleet again "
            "(roslink-mqtt acl export --format mosquitto --out DIR --config config/robots.yaml; "
            "replace DIR with /etc/mosquitto/roslink in mosquitto.conf)")
