"""``roslink-mqtt fleet user|grant|revoke`` (roslink_mqtt/config/edit.py): robots.yaml changed in place with its
comments, anchors and layout kept, each change checked as the broker would before the file is replaced."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from roslink_mqtt.cli.main import main
from roslink_mqtt.config import Role, load_fleet, verify_password
from roslink_mqtt.config.edit import FleetEdit, FleetEditError
from roslink_mqtt.config.passwords import hash_password

DEMO = Path(__file__).resolve().parents[2] / "config" / "robots.yaml"


@pytest.fixture
def fleet_file(tmp_path: Path) -> Path:
    path = tmp_path / "robots.yaml"
    shutil.copy(DEMO, path)
    path.chmod(0o640)
    return path


def test_a_user_granted_then_revoked_then_removed_and_nothing_else_changes(fleet_file: Path) -> None:
    original = fleet_file.read_text().splitlines()
    edit = FleetEdit(fleet_file)
    edit.add_user("dave", hash_password("dave-secret", iterations=1000))
    assert edit.grant("dave", "turtle1", Role.VIEWER) and edit.grant("dave", "turtle1", Role.OPERATOR)
    assert not edit.grant("dave", "turtle1", Role.OPERATOR)  # already so: nothing to change
    edit.save()
    fleet = load_fleet(fleet_file)
    assert fleet.users_of("turtle1")["dave"] is Role.OPERATOR and "dave" not in fleet.users_of("turtle2")
    text = fleet_file.read_text()
    lines = iter(text.splitlines())  # every line of the author's file is still there, in order: only dave added
    assert all(any(line == new for new in lines) for line in original)
    assert "- {key: demo-key-turtle1, role: operator}" in text and oct(fleet_file.stat().st_mode & 0o777) == "0o640"

    edit = FleetEdit(fleet_file)
    edit.revoke("dave", "turtle1")
    edit.save()
    assert "dave" not in load_fleet(fleet_file).users_of("turtle1")
    edit = FleetEdit(fleet_file)
    edit.remove_user("dave")
    edit.save()
    assert fleet_file.read_text().splitlines() == original  # back to the author's file, byte for byte


@pytest.mark.parametrize(("change", "why"), [
    (lambda e: e.grant("alice", "turtle9", Role.OPERATOR), "no robot 'turtle9'"),
    (lambda e: e.grant("zed", "turtle1", Role.OPERATOR), "no user 'zed'"),
    (lambda e: e.add_user("alice", "$7$1000$x$y"), "user 'alice' is already in"),
    (lambda e: e.add_user("turtle1", "$7$1000$x$y"), "a robot's login"),
    (lambda e: e.revoke("bob", "turtle2"), "user 'bob' has no grant on turtle2"),
])
def test_an_edit_that_cannot_be_made_says_why(fleet_file: Path, change, why: str) -> None:
    with pytest.raises(FleetEditError, match=why):
        change(FleetEdit(fleet_file))


def test_an_edit_the_broker_would_refuse_is_not_written(fleet_file: Path) -> None:
    before = fleet_file.read_text()
    edit = FleetEdit(fleet_file)
    edit.add_user("eve", "not a hash")
    with pytest.raises(FleetEditError, match="not written, the fleet would be invalid: .*users.eve"):
        edit.save()
    assert fleet_file.read_text() == before


def test_the_cli_makes_a_password_grants_and_says_to_apply(fleet_file: Path, tmp_path: Path, capsys) -> None:
    password_file = tmp_path / "dave.password"
    assert main(["fleet", "user", "add", "dave", "--config", str(fleet_file), "--password-file",
                 str(password_file), "--iterations", "1000"]) == 0
    password = password_file.read_text().strip()
    assert len(password) >= 20 and oct(password_file.stat().st_mode & 0o777) == "0o600"
    assert verify_password(password, load_fleet(fleet_file).users["dave"].password_hash)
    line = next(n for n in fleet_file.read_text().splitlines() if "$7$" in n and "dave" not in n and
                load_fleet(fleet_file).users["dave"].password_hash in n)
    assert line.strip().startswith("password: $7$")  # on one line with its key, never folded onto the next
    assert main(["fleet", "grant", "dave", "turtle2", "--role", "viewer", "--config", str(fleet_file)]) == 0
    assert "dave is now viewer of turtle2; apply it with `roslink-mqtt fleet apply`" in capsys.readouterr().out
    assert load_fleet(fleet_file).users_of("turtle2")["dave"] is Role.VIEWER
    assert main(["fleet", "revoke", "dave", "turtle1", "--config", str(fleet_file)]) == 2
    assert "roslink-mqtt fleet: user 'dave' has no grant on turtle1" in capsys.readouterr().err


def test_robot_add_writes_the_robot_and_a_bundle_that_holds_nothing_of_anyone_else(fleet_file: Path,
                                                                                  tmp_path: Path) -> None:
    original = fleet_file.read_text().splitlines()
    bundle = tmp_path / "bundle"
    assert main(["fleet", "robot", "add", "--config", str(fleet_file), "turtle3", "--bundle", str(bundle),
                 "--like", "turtle1", "--broker-url", "mqtts://broker.example.net:8883"]) == 0
    fleet = load_fleet(fleet_file, need_hashes=True)
    turtle3, turtle1 = fleet.robots["turtle3"], fleet.robots["turtle1"]
    assert turtle3.system_id == 3 and turtle3.key not in (r.key for r in fleet.robots.values() if r is not turtle3)
    assert turtle3.rules == turtle1.rules and turtle3.bridge.broker_url == "mqtts://broker.example.net:8883"
    assert turtle1.bridge.broker_url != turtle3.bridge.broker_url  # its own bridge settings, not the template's changed
    lines = iter(fleet_file.read_text().splitlines())  # the author's file, only turtle3 added
    assert all(any(line == new for new in lines) for line in original)
    password = (bundle / "turtle3.password").read_text().strip()
    assert len(password) >= 24 and verify_password(password, turtle3.password_hash)
    robot_file = (bundle / "turtle3.yaml").read_text()
    assert "$7$" not in robot_file and turtle1.key not in robot_file and "alice" not in robot_file
    assert load_fleet(bundle / "turtle3.yaml").robot_file == "turtle3"
    env = dict(line.split("=", 1) for line in (bundle / "turtle3.env").read_text().splitlines()
               if line and not line.startswith("#"))
    assert env["ROSLINK_ROBOT"] == "turtle3" and "ROSLINK_PASSWORD" not in env and password not in str(env)
    assert env["ROSLINK_BRIDGE_ARGS"] == "--url mqtts://broker.example.net:8883"
    for private in ("turtle3.password", "turtle3.env", "turtle3.yaml"):
        assert oct((bundle / private).stat().st_mode & 0o777) == "0o600", private
    drop_in = (bundle / "roslink-mqtt-bridge.service.d" / "turtle3.conf").read_text().splitlines()
    # systemd: an empty assignment resets the unit's list, so the drop-in replaces, never adds a second command
    assert drop_in.index("ExecStart=") < drop_in.index(next(x for x in drop_in if x.startswith("ExecStart=/")))
    assert "EnvironmentFile=/etc/roslink-mqtt/turtle3.env" in drop_in and "EnvironmentFile=" in drop_in
    assert any("--config /etc/roslink-mqtt/turtle3.yaml" in x and "--password-file /etc/roslink-mqtt/turtle3.password"
               in x for x in drop_in)


@pytest.mark.parametrize("args, why", [
    (["turtle1"], "robot 'turtle1' is already in"),
    (["alice"], "'alice' is a user's login"),
    (["turtle3", "--like", "turtle9"], "no robot 'turtle9'"),
])
def test_robot_add_refuses_with_a_reason(fleet_file: Path, tmp_path: Path, capsys, args: list[str],
                                         why: str) -> None:
    before = fleet_file.read_text()
    assert main(["fleet", "robot", "add", "--config", str(fleet_file), "--bundle", str(tmp_path / "b"),
                 *args]) == 2
    assert why in capsys.readouterr().err and fleet_file.read_text() == before
    assert not (tmp_path / "b").exists()
