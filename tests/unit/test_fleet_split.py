"""``fleet split``: a robot file holds its robot and nothing of anyone else (no users: its grants come from the
broker); the loader keeps it that way (a password or a users section in it is refused) and the broker side refuses
to run from it. The grants message the broker sends (protocol/grants.py) turns it back into the fleet's roles."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from roslink_mqtt.config import ConfigError, load_fleet, parse_fleet
from roslink_mqtt.config.grants import grants_of, with_grants
from roslink_mqtt.config.split import split_fleet
from roslink_mqtt.protocol.errors import ProtocolError
from roslink_mqtt.protocol.grants import RobotGrants

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "config" / "robots.yaml"


def _lineless(entries: tuple) -> tuple:
    return tuple(dataclasses.replace(e, line=0) for e in entries)


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("split")
    return {p.stem: p for p in split_fleet(DEMO, out)}


def test_each_robot_gets_a_file_without_hashes_or_other_robots(files) -> None:
    fleet = load_fleet(DEMO)
    assert sorted(files) == sorted(fleet.robots)
    for robot, path in files.items():
        text = path.read_text()
        assert "$7$" not in text and "password:" not in text
        others = [r for r in fleet.robots.values() if r.name != robot]
        assert not any(r.key in text or f"{r.name}:" in text for r in others), text
        assert path.stat().st_mode & 0o777 == 0o600  # the robot's own key is in it
        split = load_fleet(path)
        assert split.robot_file == robot and list(split.robots) == [robot]
        assert split.users == {} and split.grants_pending and "users:" not in text
        assert not any(f"{user}:" in text for user in fleet.users)
        message = grants_of(fleet, robot, issued=1.0, by="broker").to_json()
        granted = with_grants(split, RobotGrants.from_json(message))
        assert granted.users_of(robot) == fleet.users_of(robot) and not granted.grants_pending
        assert all(u.password_hash == "" for u in granted.users.values())
        mine, theirs = split.robots[robot], fleet.robots[robot]
        for part in ("rules", "services", "actions", "parameters"):  # the same, but at other lines of another file
            assert _lineless(getattr(mine, part)) == _lineless(getattr(theirs, part)), part
        assert (mine.bridge, mine.key, mine.control, mine.estop) == (theirs.bridge, theirs.key, theirs.control,
                                                                     theirs.estop)
        assert mine.password_hash == ""


def test_only_the_robots_named_are_written_and_an_unknown_one_is_refused(tmp_path) -> None:
    assert [p.name for p in split_fleet(DEMO, tmp_path, ["turtle2"])] == ["turtle2.yaml"]
    with pytest.raises(ConfigError, match="no robot 'turtle9' in the fleet"):
        split_fleet(DEMO, tmp_path, ["turtle9"])


def test_a_password_or_users_in_a_robot_file_are_refused_where_they_are(files) -> None:
    data = yaml.safe_load(files["turtle1"].read_text())
    data["robots"]["turtle1"]["password"] = load_fleet(DEMO).robots["turtle1"].password_hash
    with pytest.raises(ConfigError, match=r"robots\.turtle1\.password: a robot file holds no password hash"):
        parse_fleet(yaml.safe_dump(data), "turtle1.yaml")
    del data["robots"]["turtle1"]["password"]
    data["users"] = {"alice": {"grants": [{"key": load_fleet(DEMO).robots["turtle1"].key, "role": "operator"}]}}
    with pytest.raises(ConfigError, match=r"users: a robot file holds no users: its bridge takes the robot's grants "
                                          r"from the broker"):
        parse_fleet(yaml.safe_dump(data), "turtle1.yaml")


@pytest.mark.parametrize("body, why", [
    (b'{"robot": "turtle1", "users": {"alice": "driver"}, "issued": 1}', "users.alice: expected one of operator"),
    (b'{"robot": "turtle1", "users": {"a/b": "operator"}, "issued": 1}', "users: user 'a/b' must not contain '/'"),
    (b'{"robot": "turtle1", "users": ["alice"], "issued": 1}', "users: expected object of strings"),
    (b'{"robot": "turtle1", "issued": 1}', "users: missing"),
    (b'[]', "expected a JSON object"),
])
def test_a_malformed_grants_message_is_refused_with_its_reason(body: bytes, why: str) -> None:
    with pytest.raises(ProtocolError, match=why.replace(".", r"\.").replace("(", r"\(")):
        RobotGrants.from_json(body)


def test_a_robot_file_holds_its_own_robot_only(files) -> None:
    data = yaml.safe_load(files["turtle1"].read_text())
    data["robot_file"] = "turtle2"
    with pytest.raises(ConfigError, match="a robot file holds its own robot only \\('turtle2'\\), found: turtle1"):
        parse_fleet(yaml.safe_dump(data), "turtle1.yaml")


def test_the_broker_and_the_exports_refuse_a_robot_file(files) -> None:
    with pytest.raises(ConfigError, match="this is the robot file of turtle1 .* need the fleet file"):
        load_fleet(files["turtle1"], need_hashes=True)
    assert load_fleet(DEMO, need_hashes=True).robot_file is None
