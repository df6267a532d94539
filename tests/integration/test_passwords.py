"""Password hashes are interchangeable with Mosquitto, proven with the real tools."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from roslink_mqtt.config import verify_password
from roslink_mqtt.config.passwords import PasswordHashError, check_hash_format, hash_password
from tests.support.mosquitto import run_mosquitto
from tests.support.waits import wait_until

MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd")


def test_hash_and_verify() -> None:
    h = hash_password("s3cret", iterations=1000)
    assert h.startswith("$7$1000$")
    assert verify_password("s3cret", h)
    assert not verify_password("s3cret ", h)
    assert hash_password("x", iterations=1000) != hash_password("x", iterations=1000)  # salted


@pytest.mark.parametrize("bad", ["", "plain", "$7$abc$c2FsdA==$aGFzaA==", "$7$0$c2FsdA==$aGFzaA==",
                                 "$7$10$%%%$aGFzaA==", "$5$x$y"])
def test_bad_hash_formats(bad: str) -> None:
    with pytest.raises(PasswordHashError):
        check_hash_format(bad)


def test_mosquitto_passwd_hash_verifies_in_our_code(tmp_path: Path) -> None:
    pwfile = tmp_path / "pw"
    subprocess.run([MOSQUITTO_PASSWD, "-c", "-b", str(pwfile), "alice", "alice-demo"], check=True)
    user, stored = pwfile.read_text().strip().split(":", 1)
    assert user == "alice" and stored.startswith("$7$")
    assert verify_password("alice-demo", stored)
    assert not verify_password("alice-demo2", stored)
    # The legacy sha512 format Mosquitto 1.6 wrote is verified too.
    subprocess.run([MOSQUITTO_PASSWD, "-H", "sha512", "-b", str(pwfile), "bob", "bob-demo"], check=True)
    legacy = dict(line.split(":", 1) for line in pwfile.read_text().split())["bob"]
    assert legacy.startswith("$6$") and verify_password("bob-demo", legacy)


def _connect_rc(port: int, username: str, password: str) -> int:
    result: list[int] = []
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"t-{username}")
    client.username_pw_set(username, password)
    client.on_connect = lambda c, u, f, rc, p: result.append(rc.value)
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        wait_until("a CONNACK", lambda: result, timeout=5)
    finally:
        client.loop_stop()
        client.disconnect()
    assert result, "no CONNACK"
    return result[0]


def test_passwd_reads_a_pipe_without_warning_and_refuses_short_passwords() -> None:
    def passwd(text: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "passwd", "dave"], input=text,
                              capture_output=True, text=True, timeout=30)

    piped = passwd("dave-is-here\n")  # no --stdin: stdin is not a terminal
    assert piped.returncode == 0 and piped.stdout.startswith("dave:$7$"), piped.stderr
    assert "Warning" not in piped.stderr, piped.stderr  # getpass used to warn that it would echo
    short = passwd("x\n")
    assert short.returncode == 1 and "a password of 1 character refused: at least 8" in short.stderr
    assert "empty password refused" in passwd("\n").stderr


def test_our_cli_hash_is_accepted_by_mosquitto(tmp_path: Path) -> None:
    out = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "passwd", "--stdin", "carol"],
                         input="carol-demo\n", capture_output=True, text=True, check=True).stdout.strip()
    assert out.startswith("carol:$7$")
    (tmp_path / "passwd").write_text(out + "\n")
    conf = f"allow_anonymous false\npassword_file {tmp_path / 'passwd'}\n"
    with run_mosquitto(tmp_path, conf) as port:
        assert _connect_rc(port, "carol", "carol-demo") == 0
        assert _connect_rc(port, "carol", "wrong") != 0
