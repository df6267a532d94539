"""roslink_mqtt.localproc: the one helper the demo, the benchmarks and the tests use to run local processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from roslink_mqtt.config import load_fleet
from roslink_mqtt.localproc import ChildExited, LocalProcess, fleet_copy, free_port, replace_once, wait_for_port
from tests.support.broker_setup import write_fleet
from tests.support.procs import CONFIG
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(60)

OLD_BENCH_EDIT = ("  port: 1883\n  ws_port: 8083\n", "  port: {port}\n  ws_port: 0\n")  # bench/broker_acl.py's


def reformatted_demo_fleet(tmp_path: Path) -> Path:
    """The demo fleet with the same content but its broker keys in another order: a harmless edit of the file."""
    data = yaml.safe_load(CONFIG.read_text())
    broker = data["broker"]
    data["broker"] = {"ws_port": broker.pop("ws_port"), **broker}
    path = tmp_path / "reformatted.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_the_old_text_edit_silently_did_nothing_and_now_fails(tmp_path: Path) -> None:
    source = reformatted_demo_fleet(tmp_path)
    text, port = source.read_text(), free_port()
    old, new = OLD_BENCH_EDIT
    assert text.replace(old, new.format(port=port)) == text  # the old way: no error, still port 1883
    with pytest.raises(ValueError, match="exactly one"):
        replace_once(text, old, new.format(port=port))


def test_fleet_copy_edits_the_data_whatever_the_layout(tmp_path: Path) -> None:
    port = free_port()
    copy = fleet_copy(tmp_path / "copy.yaml", reformatted_demo_fleet(tmp_path), port=port, ws_port=0)
    fleet = load_fleet(copy)
    assert fleet.broker.port == port and not fleet.broker.ws_port  # 0: no WebSocket listener
    assert set(fleet.robots) == set(load_fleet(CONFIG).robots)


def test_fleet_copy_refuses_an_edit_that_breaks_the_fleet(tmp_path: Path) -> None:
    with pytest.raises(Exception):  # noqa: B017 - the config loader's own error, whichever it is
        fleet_copy(tmp_path / "broken.yaml", CONFIG, edit=lambda data: data["robots"]["turtle1"].update(key=7))


def test_write_fleet_refuses_an_edit_that_changes_nothing(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="changed nothing"):
        write_fleet(tmp_path, edit=lambda t: t.replace("text that is not in the file", "x"))


def _gone(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state == "Z"


def test_stop_ends_a_stubborn_child_and_what_it_started(tmp_path: Path) -> None:
    """SIGINT ignored -> SIGKILL after the timeout; the grandchild (same process group) goes too."""
    script = ("import signal, subprocess, sys, time\n"
              "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
              "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
              "g = subprocess.Popen(['sleep', '60'])\n"
              "print(g.pid, flush=True)\n"
              "time.sleep(60)\n")
    child = LocalProcess([sys.executable, "-c", script], tmp_path / "child.log")
    child.spawn()
    wait_until("the child to print its child's pid", lambda: child.output().strip(), timeout=10)
    grandchild = int(child.output().split()[0])
    assert os.getpgid(grandchild) == child.pid  # a process group of its own, led by the child
    started = time.monotonic()
    assert child.stop(timeout=0.5) == -signal.SIGKILL
    assert time.monotonic() - started < 5
    wait_until("the grandchild to be gone", lambda: _gone(grandchild), timeout=5)


def test_stop_sends_the_stop_signal_first_and_survives_a_frozen_child(tmp_path: Path) -> None:
    child = LocalProcess([sys.executable, "-c", "import time; time.sleep(60)"], tmp_path / "c.log",
                         stop_signal=signal.SIGTERM)
    child.spawn()
    child.signal(signal.SIGSTOP)
    assert child.stop(timeout=5) == -signal.SIGTERM  # SIGCONT first, so the SIGTERM is handled, no SIGKILL


def test_wait_for_port_fails_fast_with_the_log_when_the_child_exits(tmp_path: Path) -> None:
    log = tmp_path / "early.log"
    child = LocalProcess([sys.executable, "-c", "print('cannot bind, giving up'); raise SystemExit(3)"], log,
                         port=free_port(), what="the broker")
    started = time.monotonic()
    with pytest.raises(ChildExited, match=r"(?s)the broker exited \(code 3\).*cannot bind, giving up"):
        child.start()
    assert time.monotonic() - started < 5


def test_wait_for_port_times_out() -> None:
    with pytest.raises(TimeoutError):
        wait_for_port(free_port(), timeout=0.3)


def test_localproc_imports_neither_rclpy_nor_amqtt() -> None:
    code = ("import sys, roslink_mqtt.localproc, roslink_mqtt.demo\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'amqtt'))\n"
            "print(bad)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30, check=True)
    assert out.stdout.strip() == "[]"
