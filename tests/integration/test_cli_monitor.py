"""``roslink-mqtt monitor``: the fleet view's rules with a fake clock, then the command against a real stack."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import threading

import pytest

from roslink_mqtt.cli import monitor_cmd
from roslink_mqtt.cli.monitor_view import HEADERS, FleetView, Row, fit_columns, number, presence
from roslink_mqtt.client import RobotError, RobotInfo
from roslink_mqtt.client.messages import Ack, GlobalMotion, GpsRawInfo, RobotStatus
from roslink_mqtt.protocol import AckResult, FlightMode, RobotType, SystemStatus
from roslink_mqtt.protocol.link import LinkReport, StreamReport
from tests.support.procs import ROOT
from tests.support.robot_stack import turtle1_online


class FakeClock:
    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def heartbeat(at: float, status: SystemStatus = SystemStatus.ACTIVE, owner: str = "alice",
              stale_after: float = 5.0) -> RobotInfo:
    return RobotInfo("turtle1", 1, RobotType.GROUND, status, FlightMode.MANUAL, owner, 3, at, stale_after)


def motion(robot: str = "turtle1", **fields: float) -> GlobalMotion:
    values = dict.fromkeys(("x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz", "roll", "pitch", "yaw"), 0.0)
    return GlobalMotion(**{**values, **fields}, robot=robot)


def status(remaining: float = 87.0, voltage: float = 12.14) -> RobotStatus:
    return RobotStatus(voltage_battery=voltage, current_battery=-1.5, battery_remaining=remaining, robot="turtle1")


def gps(fix: int = 3) -> GpsRawInfo:
    return GpsRawInfo(fix_type=fix, lat=24.7136, lon=46.6753, alt=612.0, robot="turtle1")


def only_row(view: FleetView) -> Row:
    rows = view.rows()
    assert len(rows) == 1
    return rows[0]


# -- the view: pure logic ----------------------------------------------------------------------------------------

def test_named_robot_without_data_is_all_dashes() -> None:
    view = FleetView(clock=FakeClock())
    view.watch("turtle1")
    row = only_row(view)
    assert row.robot == "turtle1" and row.presence == "unseen"
    assert set(row[2:]) == {"-"}
    assert view.seen() == []  # named but silent: the command exits 1


def test_row_with_every_stream() -> None:
    clock = FakeClock(100.0)
    view = FleetView(clock=clock)
    view.update_robots({"turtle1": heartbeat(99.5)})
    view.record(status(), at=98.0)
    view.record(motion(x=1.5, y=-2.25, yaw=math.pi / 2, vx=0.3, wz=-0.5), at=99.0)
    view.record(gps(), at=99.2)
    view.record(Ack(command=0, command_sequence=-1, result=int(AckResult.FAILSAFE), text="operator alice went away",
                    robot="turtle1"), at=99.6)
    row = only_row(view)
    assert row == Row(robot="turtle1", presence="online", status="active", type="ground", mode="manual",
                      owner="alice", battery="87%", voltage="12.1V", x="1.50", y="-2.25", yaw="90", vx="0.30",
                      wz="-0.50", gps="3D", lat="24.713600", lon="46.675300", rate="-", age="0.4s",
                      link="-", ack="failsafe: operator alice went away")
    assert view.seen() == ["turtle1"]


def test_the_uplink_column_shows_the_rate_and_the_stream_furthest_behind() -> None:
    view = FleetView(clock=FakeClock(10.0))
    view.watch("turtle1")
    view.record_link("turtle1", {"not": "a report"})  # a generic rule's dict on that name: ignored
    assert only_row(view).link == "-"
    report = LinkReport("scheduled", 243.6, True, 3300, 81.0, 2.0, {
        "global_motion": StreamReport("motion", True, 10.0, 10.0),
        "range_finder_data": StreamReport("state", True, 5.0, 3.9, superseded=2),
        "gps_raw_info": StreamReport("state", True, 1.0, 0.5)})
    view.record_link("turtle1", report)
    assert only_row(view).link == "244k gps_raw_info 0.5/1"
    view.record_link("turtle1", LinkReport("scheduled", 900.0, False, 20000, 1.0, 2.0, {
        "global_motion": StreamReport("motion", True, 10.0, 10.0)}))
    assert only_row(view).link == "≥900k"  # the link had room: its rate is at least this


def test_presence_online_offline_stale() -> None:
    assert presence(None, 10.0) == "unseen"
    assert presence(heartbeat(at=9.0), 10.0) == "online"
    assert presence(heartbeat(at=9.0, status=SystemStatus.EMERGENCY), 10.0) == "online"  # blocked, yet connected
    assert presence(heartbeat(at=9.9, status=SystemStatus.OFFLINE), 10.0) == "offline"  # the bridge's last-will
    assert presence(heartbeat(at=4.0, stale_after=5.0), 10.0) == "stale"  # no will, but no heartbeat either
    clock = FakeClock(50.0)
    view = FleetView(clock=clock)
    view.update_robots({"turtle1": heartbeat(at=49.0)})
    assert only_row(view).presence == "online"
    clock.now = 60.0
    assert only_row(view).presence == "stale"
    view.update_robots({})  # the retained heartbeat was cleared
    assert only_row(view).presence == "unseen"


def test_rate_over_a_two_second_window() -> None:
    clock = FakeClock(0.0)
    view = FleetView(clock=clock, rate_window=2.0)
    assert view.rate("turtle1") is None
    view.record(motion(), at=0.0)
    assert view.rate("turtle1", now=0.05) is None  # one message says nothing about a rate
    for i in range(1, 4):
        view.record(motion(), at=i * 0.1)
    assert view.rate("turtle1", now=0.3) == pytest.approx(10.0)  # window not full yet: from the spacing
    for i in range(4, 21):  # 10 Hz for two seconds
        view.record(motion(), at=i * 0.1)
    clock.now = 2.0
    assert view.rate("turtle1") == pytest.approx(10.0)
    assert only_row(view).rate == "10.0"
    assert view.rate("turtle1", now=3.0) == pytest.approx(5.0)  # stream stopped at 2.0: half the window is empty
    assert view.rate("turtle1", now=10.0) == 0.0
    clock.now = 10.0
    assert only_row(view).rate == "0.0"


def test_missing_and_non_finite_values_show_dashes() -> None:
    view = FleetView(clock=FakeClock(10.0))
    view.record(status(remaining=-1.0, voltage=math.nan), at=9.0)  # -1 = unknown charge
    view.record(motion(x=math.nan, y=math.inf, yaw=-math.inf, vx=1e308 * 10, wz=0.25), at=9.0)
    view.record(gps(fix=1), at=9.0)  # no fix: lat/lon mean nothing
    row = only_row(view)
    assert (row.battery, row.voltage, row.x, row.y, row.yaw, row.vx) == ("-",) * 6
    assert row.wz == "0.25" and row.gps == "no fix" and row.lat == row.lon == "-"
    assert row.presence == "unseen" and row.status == "-" and row.owner == "-"
    assert row.age == "1.0s"
    for junk in (None, "3", True, math.nan, -math.inf, [1.0]):
        assert number(junk) == "-"


def test_negative_yaw_in_degrees_and_unknown_enum_values() -> None:
    view = FleetView(clock=FakeClock(1.0))
    info = RobotInfo("turtle1", 1, 42, 77, 99, "", 0, 1.0)  # values newer than this client's enums
    view.update_robots({"turtle1": info})
    view.record(motion(yaw=-math.pi / 4), at=1.0)
    view.record(gps(fix=9), at=1.0)
    view.record(Ack(command=100, command_sequence=5, result=200, text="", robot="turtle1"), at=1.0)
    row = only_row(view)
    assert (row.type, row.status, row.mode, row.owner) == ("42", "77", "99", "-")
    assert row.yaw == "-45" and row.gps == "fix 9" and row.ack == "result 200"


def test_ignores_what_it_does_not_understand() -> None:
    view = FleetView(clock=FakeClock())
    view.record({"data": 1})  # a generic rule's plain ROS JSON
    view.record(motion(robot=""))  # no robot to put it under
    view.record("garbage")
    assert view.rows() == []


def test_error_footer() -> None:
    clock = FakeClock(20.0)
    view = FleetView(clock=clock)
    assert view.errors() == []
    for i in range(7):
        view.record_error(RobotError("turtle1", f"roslink/turtle1/from/alice/cmd/n{i}", f"reason {i}"), at=17.0)
    view.record_error(RobotError("turtle1", "", ""), at=19.5)
    lines = view.errors(limit=3)
    assert lines == ["turtle1 refused cmd/n5: reason 5 (3.0s ago)", "turtle1 refused cmd/n6: reason 6 (3.0s ago)",
                     "turtle1 refused -: - (0.5s ago)"]
    assert view.errors(limit=0) == []


def test_feeding_and_reading_from_different_threads() -> None:
    view = FleetView()
    stop = threading.Event()
    failures: list[BaseException] = []

    def feed(robot: str) -> None:
        try:
            while not stop.is_set():
                view.record(motion(robot=robot, x=1.0))
                view.record_error(RobotError(robot, "t", "e"))
        except BaseException as err:  # reported below
            failures.append(err)

    threads = [threading.Thread(target=feed, args=(f"r{i}",)) for i in range(3)]
    for t in threads:
        t.start()
    try:
        for _ in range(300):
            view.rows()
            view.errors()
            view.update_robots({})
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert not failures
    assert [r.robot for r in view.rows()] == ["r0", "r1", "r2"]


def test_fit_columns_drops_the_least_useful_first() -> None:
    view = FleetView(clock=FakeClock(10.0))
    view.update_robots({"turtle1": heartbeat(9.5)})
    view.record(motion(x=1.0), at=9.9)
    view.record(gps(), at=9.9)
    rows = view.rows()
    assert fit_columns(rows, 400) == list(Row._fields)
    narrow = fit_columns(rows, 80)
    assert {"robot", "presence", "battery", "x", "y", "ack"} <= set(narrow)
    assert not {"lat", "lon", "type", "status"} & set(narrow)
    used = sum(max(len(getattr(HEADERS, k)), *(len(getattr(r, k)) for r in rows)) + 3 for k in narrow) - 3
    assert used <= 80


def test_plain_output_keeps_text_literal(capsys) -> None:
    pytest.importorskip("rich")
    view = FleetView(clock=FakeClock(5.0))
    view.update_robots({"turtle1": heartbeat(4.5)})
    view.record(Ack(command=0, command_sequence=-1, result=3, text="stop [red]now[/red]", robot="turtle1"), at=4.8)
    view.record_error(RobotError("turtle1", "roslink/turtle1/from/bob/cmd/twist", "[bold]not allowed"), at=4.0)
    monitor_cmd._print_plain(view, "fleet", errors=5)
    out = capsys.readouterr().out
    assert "failsafe: stop [red]now[/red]" in out and "turtle1 refused cmd/twist: [bold]not allowed" in out
    assert "\x1b[" not in out and all(line == line.rstrip() for line in out.splitlines())
    header = next(line for line in out.splitlines() if line.lstrip().startswith("robot"))
    assert "presence" in header and "lat" in header  # a file gets every column


def test_without_rich_the_command_says_how_to_get_it() -> None:
    code = ("import sys; sys.modules['rich'] = None\n"
            "from roslink_mqtt.cli.main import main\n"
            "sys.exit(main(['monitor', '--once', '-u', 'bob']))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=30,
                         stdin=subprocess.DEVNULL)
    assert out.returncode == 2, out.stdout + out.stderr
    assert "roslink-mqtt monitor needs rich: pip install 'roslink-mqtt[cli]'" in out.stderr
    assert "Traceback" not in out.stderr


def test_core_imports_do_not_pull_in_rich() -> None:
    code = ("import sys\nimport roslink_mqtt.client, roslink_mqtt.cli.main\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'rich'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=30)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


# -- the command against a real stack ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def port(tmp_path_factory):
    work = tmp_path_factory.mktemp("monitor")
    with turtle1_online(work) as broker_port:
        yield broker_port


def monitor(port: int, user: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "monitor", *args,
                           "--url", f"mqtt://127.0.0.1:{port}", "-u", user], capture_output=True, text=True,
                          env=env, cwd=ROOT, timeout=30, stdin=subprocess.DEVNULL)


def cell(header: str, row: str, title: str) -> str:
    """The right-aligned cell under ``title`` in a plain table row."""
    end = header.index(title) + len(title)
    return row[:end].split()[-1]


@pytest.mark.timeout(60)
def test_monitor_once_shows_live_state(port) -> None:
    out = monitor(port, "bob", "--once", "--wait", "3")
    assert out.returncode == 0, out.stdout + out.stderr
    lines = out.stdout.splitlines()
    header = next(line for line in lines if line.startswith("robot"))
    row = next(line for line in lines if line.startswith("turtle1"))
    assert row.split()[:4] == ["turtle1", "online", "active", "ground"], out.stdout
    assert re.search(r" \d{1,3}% ", row), row  # the sim's battery, through the robot_status preset
    x, yaw, rate = (float(cell(header, row, t)) for t in ("x m", "yaw°", "motion Hz"))
    assert math.isfinite(x) and -180 <= yaw <= 180 and rate > 0, row
    assert " 3D " in row  # the sim has a GPS fix
    assert "turtle2" not in out.stdout  # bob may not see it


@pytest.mark.timeout(60)
def test_monitor_without_visible_robots_exits_1(port) -> None:
    out = monitor(port, "carol", "--once", "--wait", "1")  # carol operates turtle2 only; no bridge runs for it
    assert out.returncode == 1, out.stdout + out.stderr
    assert "turtle1" not in out.stdout and "no robots seen" in out.stdout


def test_driven_by_comes_from_the_control_state() -> None:
    from datetime import datetime

    from roslink_mqtt.protocol.lease import ControlState

    view = FleetView(clock=FakeClock(10.0))
    view.watch("turtle1")
    view.record_control("turtle1", {"holder": "alice"})  # not a ControlState: ignored
    assert only_row(view).owner == "-"
    since = 1764158585.0
    view.record_control("turtle1", ControlState("alice", since, supervisor=True))
    clock = datetime.fromtimestamp(since).strftime("%H:%M:%S")
    assert only_row(view).owner == f"alice (supervisor) since {clock}"
    view.record_control("turtle1", ControlState(None, None))
    assert only_row(view).owner == "-"
