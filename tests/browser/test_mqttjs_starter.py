"""The MQTT.js starters (plain MQTT.js, no SDK) against a real stack: embedded broker, sim robot, bridge.

* examples/mqttjs/watch_and_drive.js (Node): what counts is checked where it happens -- the twists on ROS
  ``/cmd_vel`` and the robot's displacement on ``/odom``; the script's own output must show the robot's heartbeat
  and a position that changes. Killing the script mid-drive must stop the robot through its last-will.
* examples/mqttjs/index.html in headless Debian Chromium (Selenium) over the broker's WebSocket listener: holding
  forward moves the robot, releasing stops it, closing the browser stops it. The times are printed.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from tests.support.measure import record_measurement
from tests.support.procs import ROOT
from tests.support.ros import RosProbe
from tests.support.stack import live_robot
from tests.support.waits import never, stays, wait_until

pytestmark = pytest.mark.timeout(120)

SCRIPT = ROOT / "examples" / "mqttjs" / "watch_and_drive.js"
NODE = shutil.which("node")
POSITION = re.compile(r"^position turtle1: x=(-?\d+\.\d+) y=(-?\d+\.\d+) ", re.M)


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    assert NODE, "node is not installed (.ci/run installs nodejs)"
    assert (ROOT / "node_modules" / "mqtt").is_dir(), "MQTT.js missing: run `make install` (npm ci)"
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry

    work = tmp_path_factory.mktemp("mqttjs")
    with live_robot(work, "embedded", ws=True) as live:
        probe = RosProbe()
        try:
            yield {"port": live.port, "ws_port": live.ws_port, "cmd_vel": probe.watch(Twist, "/cmd_vel"),
                   "odom": probe.watch(Odometry, "/odom")}
        finally:
            probe.close()


def _env(port: int, user: str, password: str) -> dict[str, str]:
    return {**os.environ, "ROSLINK_URL": f"mqtt://127.0.0.1:{port}", "ROSLINK_USERNAME": user,
            "ROSLINK_PASSWORD": password}


def _run(port: int, user: str, password: str, *args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run([NODE, str(SCRIPT), "--robot", "turtle1", *args], env=_env(port, user, password), cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)


def _pose(odom, at: float) -> tuple[float, float]:
    """The robot's odometry position at ``at`` (the newest message not later than it)."""
    before = [m for t, m in odom.since(0) if t <= at]
    assert before, "no /odom message yet"
    p = before[-1].pose.pose.position
    return p.x, p.y


def _quiet(cmd_vel, quiet: float = 1.2, timeout: float = 10.0) -> None:
    """Until nothing reached /cmd_vel for ``quiet`` s (an earlier test's stop is republished for 0.5 s)."""
    wait_until(f"/cmd_vel to go quiet for {quiet:g} s", lambda: not cmd_vel.since(time.monotonic() - quiet),
               timeout=timeout, period=0.1)


def test_script_drives_forward_then_stops_and_prints_state(stack) -> None:
    cmd_vel, odom = stack["cmd_vel"], stack["odom"]
    odom.wait_for(lambda m: True, timeout=10)
    _quiet(cmd_vel)
    t0 = time.monotonic()
    x0, y0 = _pose(odom, t0)
    out = _run(stack["port"], "alice", "alice-demo", "--seconds", "2", "--speed", "0.3")
    t1 = time.monotonic()
    print(out.stdout, out.stderr)
    assert out.returncode == 0, out.stdout + out.stderr
    # The script saw the robot's retained heartbeat and its live position, and said what it sent.
    assert re.search(r"^heartbeat turtle1: active \(status 4\)", out.stdout, re.M), out.stdout
    assert "sent 20 twists, then stop" in out.stdout
    positions = [(float(x), float(y)) for x, y in POSITION.findall(out.stdout)]
    assert len(positions) >= 3, out.stdout
    seen = math.dist(positions[0], positions[-1])
    assert seen > 0.3, f"printed positions moved only {seen:.2f} m: {positions}"

    # ROS side: a 10 Hz stream of 0.3 m/s twists, then a zero twist after the last of them.
    forward = [(t, m) for t, m in cmd_vel.since(t0) if m.linear.x == pytest.approx(0.3) and m.angular.z == 0]
    assert len(forward) >= 15, f"{len(forward)} forward twists reached /cmd_vel"
    last_forward = forward[-1][0]
    stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=last_forward, timeout=3)
    # It moved ~0.6 m (0.3 m/s for 2 s) and stands still now.
    odom.wait_for(lambda m: m.twist.twist.linear.x == 0.0, after=stopped_at, timeout=10)
    x1, y1 = _pose(odom, time.monotonic())
    moved = math.dist((x0, y0), (x1, y1))
    print(f"turtle1 moved {moved:.2f} m on /odom ({t1 - t0:.1f} s run)")
    assert 0.4 < moved < 0.9, (x0, y0, x1, y1)
    _, last = odom.wait_for(lambda m: True, after=time.monotonic(), timeout=3)
    assert last.twist.twist.linear.x == 0.0


def test_killed_script_stops_robot_by_last_will(stack, tmp_path) -> None:
    cmd_vel = stack["cmd_vel"]
    _quiet(cmd_vel)
    t0 = time.monotonic()
    log = tmp_path / "watch_and_drive.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen([NODE, str(SCRIPT), "--robot", "turtle1", "--seconds", "20", "--speed", "0.25"],
                                env=_env(stack["port"], "alice", "alice-demo"), cwd=ROOT, stdout=out,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, process_group=0)
    try:
        cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.25), after=t0, timeout=15)
        stays("the script running (mid-drive)", lambda: proc.poll() is None, seconds=0.5)
        assert proc.poll() is None, log.read_text()
        killed = time.monotonic()
        os.killpg(proc.pid, signal.SIGKILL)
        at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=killed, timeout=3)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)
        print(log.read_text())
    took = at - killed
    print(f"MQTT.js starter SIGKILLed mid-drive: zero twist on /cmd_vel after {took * 1000:.0f} ms")
    # The last-will (empty retained presence) stops it at once; the dead-man (1 s) would be slower.
    assert took < 0.5, took
    # the failsafe's zero twists are republished for 0.5 s; then nothing may move it. A twist the script sent just
    # before the kill may still land after `killed`; none may follow the stop.
    never("a twist reaching /cmd_vel after the stop", lambda: [m for _, m in cmd_vel.since(at) if m.linear.x != 0],
          seconds=0.6)


def test_viewer_and_wrong_password_are_refused(stack) -> None:
    cmd_vel = stack["cmd_vel"]
    t0 = time.monotonic()
    bob = _run(stack["port"], "bob", "bob-demo", "--seconds", "1", "--speed", "0.4")
    assert bob.returncode == 1 and "bob only views turtle1" in bob.stderr, bob.stdout + bob.stderr
    wrong = _run(stack["port"], "alice", "not-her-password", "--seconds", "1")
    assert wrong.returncode == 1 and "cannot connect" in wrong.stderr, wrong.stdout + wrong.stderr
    assert not [m for _, m in cmd_vel.since(t0) if m.linear.x == pytest.approx(0.4)]


# -- the HTML page in headless Chromium ------------------------------------------------------------------------------
CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # the page's requests are not the test's output
        pass


@contextmanager
def _serve_repository() -> Iterator[int]:
    """The repository over HTTP on 127.0.0.1 (the page finds MQTT.js in ../../node_modules, as documented)."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(_QuietHandler, directory=str(ROOT)))
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@contextmanager
def _chromium(profile: Path) -> Iterator[object]:
    webdriver = pytest.importorskip("selenium.webdriver")
    assert CHROMIUM.exists() and CHROMEDRIVER.exists(), "chromium + chromium-driver missing (.ci/run installs them)"
    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={profile}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=str(CHROMEDRIVER)))
    try:
        driver.set_page_load_timeout(15)
        yield driver
    finally:
        driver.quit()


def test_page_drives_with_hold_and_stops_on_release_and_close(stack, tmp_path) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    cmd_vel = stack["cmd_vel"]
    _quiet(cmd_vel)
    with _serve_repository() as http_port, _chromium(tmp_path / "profile") as driver:
        driver.get(f"http://127.0.0.1:{http_port}/examples/mqttjs/index.html"
                   f"?url=ws://127.0.0.1:{stack['ws_port']}/mqtt&user=alice")
        text = lambda element_id: driver.find_element(By.ID, element_id).text  # noqa: E731
        wait_until("MQTT.js to load", lambda: driver.execute_script("return !!window.mqtt"))
        driver.find_element(By.ID, "password").send_keys("alice-demo")
        driver.find_element(By.ID, "connect").click()
        wait_until("turtle1 online", lambda: text("robot-state").startswith("online: active"))
        wait_until("the access report", lambda: text("access").startswith("operator"))
        first = wait_until("a position", lambda: text("position"))
        forward = driver.find_element(By.ID, "forward")
        assert forward.is_enabled()

        # Hold forward for 1.5 s: a 10 Hz stream of 0.3 m/s twists reaches ROS and the page sees the robot move.
        t0 = time.monotonic()
        ActionChains(driver).click_and_hold(forward).perform()
        # a 10 Hz stream while held: ten twists waited for (not slept on), then held to ~1.5 s in all
        wait_until("ten forward twists", lambda: len([m for _, m in cmd_vel.since(t0)
                                                      if m.linear.x == pytest.approx(0.3)]) >= 10)
        # and no stop meanwhile (the failsafe would send one)
        stays("no stop while forward is held", lambda: not [m for _, m in cmd_vel.since(t0)
                                                            if m.linear.x == 0 and m.angular.z == 0],
              seconds=max(0.0, t0 + 1.5 - time.monotonic()), period=0.1)
        released = time.monotonic()
        ActionChains(driver).release().perform()
        at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=released, timeout=2)
        print(f"page: released forward -> zero twist on /cmd_vel after {(at - released) * 1000:.0f} ms")
        record_measurement("MQTT.js starter: release → zero twist", at - released, 0.5)
        assert at - released < 1.0  # the goal (0.5 s) is reported; this includes WebDriver's round trip (issue 47)
        assert wait_until("a new position", lambda: text("position") != first and text("position"))
        # a twist sent just before the release may land after it, never after its zero
        never("motion after the release's zero", lambda: [m for t, m in cmd_vel.since(at)
                                                          if t > at and m.linear.x != 0], seconds=0.3)

        # Hold forward again and close the browser while holding: the last-will stops the robot.
        t1 = time.monotonic()
        ActionChains(driver).click_and_hold(forward).perform()
        cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.3), after=t1, timeout=3)
        closed = time.monotonic()
        driver.quit()
    at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=closed, timeout=3)
    print(f"page: browser closed while driving -> zero twist on /cmd_vel after {(at - closed) * 1000:.0f} ms")
    assert at - closed < 2.0  # the failsafe bound for a vanished operator (docs/safety.md)
