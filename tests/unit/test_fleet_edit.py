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
    assert main(["fleet", "grant", "dave", "turtle2", "--role", "viewer", "--config", str(fleet_file)]) == 0
    assert "dave is now viewer of turtle2; apply it with `roslink-mqtt fleet apply`" in capsys.readouterr().out
    assert load_fleet(fleet_file).users_of("turtle2")["dave"] is Role.VIEWER
    assert main(["fleet", "revoke", "dave", "turtle1", "--config", str(fleet_file)]) == 2
    assert "roslink-mqtt fleet: user 'dave' has no grant on turtle1" in capsys.readouterr().err
