"""One connection vocabulary (issue 14, item 6): the bridge, the CLI, the SDK and the examples take ``--url`` /
``ROSLINK_URL``, ``-u`` / ``ROSLINK_USERNAME`` and the password from ``ROSLINK_PASSWORD`` or ``--password-file``.

The old spellings (``--broker``, ``ROSLINK_MQTT_PASSWORD``, ``--password-env``, the examples' ``--password``)
must keep working for one release and say they are deprecated. The programs are run as child processes, the
way people run them, against a real Mosquitto with the demo fleet's logins and a real bridge.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from roslink_mqtt.connection_options import (
    DEFAULT_URL,
    ENV_PASSWORD,
    ENV_URL,
    ENV_USERNAME,
    OLD_BRIDGE_PASSWORD_ENV,
    add_connection_options,
    resolve_password,
    resolve_url,
)
from tests.support.fleet_brokers import mosquitto_with_logins
from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG, ROOT, run

CONNECTION_ENV = (ENV_URL, ENV_USERNAME, ENV_PASSWORD, OLD_BRIDGE_PASSWORD_ENV, "ROSLINK_CA_FILE")


def parse(argv: list[str], **kwargs: bool) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="t")
    add_connection_options(parser, **kwargs)
    return parser.parse_args(argv)


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in CONNECTION_ENV:
        monkeypatch.delenv(name, raising=False)
    return monkeypatch


# -- the resolver, in-process -----------------------------------------------------------------------------------
def test_url_option_beats_environment_beats_default(clean_env: pytest.MonkeyPatch) -> None:
    assert resolve_url(parse([]), "t") == DEFAULT_URL
    assert resolve_url(parse([]), "t", default=None) is None  # the bridge then uses its fleet file
    clean_env.setenv(ENV_URL, "mqtt://from-env:1884")
    assert resolve_url(parse([]), "t", default="mqtt://fleet-file") == "mqtt://from-env:1884"
    assert resolve_url(parse(["--url", "mqtt://opt:1885"]), "t") == "mqtt://opt:1885"


def test_old_broker_option_works_and_warns(clean_env: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    with pytest.warns(DeprecationWarning, match="--broker is deprecated.*use --url"):
        assert resolve_url(parse(["--broker", "mqtt://old:1886"]), "t") == "mqtt://old:1886"
    assert "t: --broker is deprecated" in caplog.text  # the line a person running the program sees


def test_password_file_beats_environment(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    assert resolve_password(parse([]), "t") is None  # nothing names one: the caller asks or falls back
    clean_env.setenv(ENV_PASSWORD, "from-env")
    assert resolve_password(parse([]), "t") == "from-env"
    secret = tmp_path / "pw"
    secret.write_text("from-file  \nsecond line ignored\n")
    assert resolve_password(parse(["--password-file", str(secret)]), "t") == "from-file"


def test_unreadable_password_file_exits_with_the_reason(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"t: cannot read password file .*missing"):
        resolve_password(parse(["--password-file", str(tmp_path / "missing")]), "t")
    (tmp_path / "empty").write_text("")
    with pytest.raises(SystemExit, match="it is empty"):
        resolve_password(parse(["--password-file", str(tmp_path / "empty")]), "t")


def test_old_password_spellings_work_and_warn(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv(ENV_PASSWORD, "shell-login")
    clean_env.setenv("MY_PW", "via-password-env")
    with pytest.warns(DeprecationWarning, match="--password-env is deprecated"):
        assert resolve_password(parse(["--password-env", "MY_PW"]), "t") == "via-password-env"
    with pytest.warns(DeprecationWarning, match="--password .*is deprecated"):
        assert resolve_password(parse(["--password", "typed"], old_password_option=True), "t") == "typed"
    # The bridge's old variable names the robot's password specifically, so it wins over a shell's login.
    clean_env.setenv(OLD_BRIDGE_PASSWORD_ENV, "robot-password")
    with pytest.warns(DeprecationWarning, match=f"{OLD_BRIDGE_PASSWORD_ENV} is deprecated.*{ENV_PASSWORD}"):
        assert resolve_password(parse([]), "t", old_env=OLD_BRIDGE_PASSWORD_ENV) == "robot-password"
    assert resolve_password(parse([]), "t") == "shell-login"  # other programs never read the bridge's old name


def test_help_shows_the_new_spellings_only(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv(ENV_URL, "mqtt://private-host:1883")
    parser = argparse.ArgumentParser(prog="t")
    add_connection_options(parser, old_password_option=True)
    text = parser.format_help()
    assert "--url" in text and "--password-file" in text and ENV_PASSWORD in text
    for hidden in ("--broker", "--password-env", "--password PASSWORD", "private-host"):
        assert hidden not in text, hidden


def test_sdk_reads_the_same_environment(clean_env: pytest.MonkeyPatch) -> None:
    from roslink_mqtt.client import RobotClient

    clean_env.setenv(ENV_USERNAME, "alice")
    client = RobotClient()
    try:
        assert client.username == "alice"
    finally:
        client.close()


# -- the programs, as child processes ---------------------------------------------------------------------------
def child_env(**values: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in CONNECTION_ENV}
    return {**env, "PYTHONUNBUFFERED": "1", **values}


def cli(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args], env=env, capture_output=True,
                          text=True, timeout=60, cwd=ROOT, stdin=subprocess.DEVNULL)


def call_from_cloud(args: list[str], env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "examples/call_from_cloud.py", "--timeout", "10", *args], env=env,
                          capture_output=True, text=True, timeout=60, cwd=ROOT, stdin=subprocess.DEVNULL)


def wait_for_heartbeat(port: int) -> None:
    with TestClient(port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe("roslink/turtle1/heartbeat")
        bob.wait_for(lambda m: m.topic == "roslink/turtle1/heartbeat", timeout=30)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[int]:
    with mosquitto_with_logins(tmp_path) as port:
        yield port


@pytest.mark.timeout(150)
def test_new_spellings_everywhere(broker: int, tmp_path: Path) -> None:
    url = f"mqtt://127.0.0.1:{broker}"
    # The bridge reads ROSLINK_URL (it used to ignore it) and ROSLINK_PASSWORD.
    bridge_env = child_env(**{ENV_URL: url, ENV_PASSWORD: "turtle1-demo"})
    with run(["-m", "roslink_mqtt.bridge.main", "--config", str(CONFIG), "--robot", "turtle1"],
             tmp_path / "bridge.log", bridge_env) as bridge:
        wait_for_heartbeat(broker)
        assert "deprecated" not in bridge.output()
        # the CLI: everything from the environment, then the options with a password file
        out = cli(["robots", "turtle1", "--wait", "1"],
                  child_env(**{ENV_URL: url, ENV_USERNAME: "alice", ENV_PASSWORD: "alice-demo"}))
        assert out.returncode == 0 and "turtle1" in out.stdout, out.stdout + out.stderr
        assert "deprecated" not in out.stderr
        secret = tmp_path / "alice.pw"
        secret.write_text("alice-demo\n")
        out = cli(["robots", "turtle1", "--wait", "1", "--url", url, "-u", "alice", "--password-file", str(secret)],
                  child_env())
        assert out.returncode == 0 and "turtle1" in out.stdout, out.stdout + out.stderr
        # the example: the password from ROSLINK_PASSWORD, not its demo default (a wrong one is refused)
        out = call_from_cloud(["--url", url], child_env(**{ENV_PASSWORD: "alice-demo"}))
        assert "turtle1 is online" in out.stdout and "deprecated" not in out.stderr, out.stdout + out.stderr
        out = call_from_cloud(["--url", url], child_env(**{ENV_PASSWORD: "wrong"}))
        assert out.returncode == 1 and "is online" not in out.stdout, out.stdout + out.stderr
    assert "deprecated" not in bridge.output()


@pytest.mark.timeout(150)
def test_old_spellings_still_work_and_warn(broker: int, tmp_path: Path) -> None:
    url = f"mqtt://127.0.0.1:{broker}"
    bridge_env = child_env(**{OLD_BRIDGE_PASSWORD_ENV: "turtle1-demo"})
    with run(["-m", "roslink_mqtt.bridge.main", "--config", str(CONFIG), "--robot", "turtle1", "--broker", url],
             tmp_path / "bridge.log", bridge_env) as bridge:
        wait_for_heartbeat(broker)
        log = bridge.output()
        assert "--broker is deprecated" in log and f"{OLD_BRIDGE_PASSWORD_ENV} is deprecated" in log, log
        out = cli(["robots", "turtle1", "--wait", "1", "--broker", url, "-u", "alice", "--password-env", "MY_PW"],
                  child_env(MY_PW="alice-demo"))
        assert out.returncode == 0 and "turtle1" in out.stdout, out.stdout + out.stderr
        assert "--broker is deprecated" in out.stderr and "--password-env is deprecated" in out.stderr, out.stderr
        out = call_from_cloud(["--url", url, "--password", "alice-demo"], child_env())
        assert "turtle1 is online" in out.stdout, out.stdout + out.stderr
        assert "--password (visible to every user in ps) is deprecated" in out.stderr, out.stderr
