"""The web dashboard in real headless Chromium (Debian's chromium + chromedriver, driven by Selenium).

One stack for the module: the embedded broker with its WebSocket listener, the simulated turtle1 and its
bridge (real processes), a ROS probe in this process watching what reaches ``/cmd_vel`` and ``/odom``, and the
dashboard's static server. Each test opens its own browser with a fresh profile and logs in as a demo user;
the page's MQTT.js connects to the broker's WebSocket itself, so everything the tests see went through the
broker's ACL. Effects are checked on the ROS side (a twist on ``/cmd_vel``, the sim's odometry), never only in
the page. A failing test saves a screenshot in its pytest tmp dir and prints the path.

Set ``DASHBOARD_SCREENSHOT=path.png`` to also save the page at the end of the memory test there
(docs/dashboard.png comes from such a run).
"""

from __future__ import annotations

import base64
import json
import math
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from roslink_mqtt.dashboard import DashboardServer
from roslink_mqtt.mqtt import WRONG_LOGIN
from roslink_mqtt.protocol.lease import ControlState
from tests.support.browser import (
    CHROMIUM,
    browser,
    click,
    logged_in,
    login,
    no_console_errors,
    robot_row,
    visible,
    wait_until,
)
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG
from tests.support.ros import RosProbe, Watch
from tests.support.stack import live_robot
from tests.support.waits import never, paced, stays

pytestmark = [pytest.mark.timeout(150), CHROMIUM]

FAILSAFE_BOUND = 2.0  # s: docs/safety.md, the worst case of an operator going away (operator_timeout 1.5 + 0.5)
# The page's e-stop click → a zero twist on /cmd_vel, at both widths. The target (issue 32) is what the summary reports
# against; the test fails only past the safety deadline (issue 47): the time includes Selenium's WebDriver round trip
# and Chromium's input routing, which a busy machine stretches without any fault of ours. bench/dashboard_estop.py
# splits the click into the browser's share and the product's (the product's p99 is the number to watch).
ESTOP_TARGET = 0.2  # s
ESTOP_DEADLINE = 1.0  # s


# -- the stack -------------------------------------------------------------------------------------------------

# The demo fleet maps only `reset` (no arguments); the forms need a service with some. The sim's own ROS
# parameter service `list_parameters` (rcl_interfaces/srv/ListParameters: `prefixes` string[], `depth` uint64)
# is mapped for turtle1 as read-only, so viewers get it too (their access report lists it).
LIST_PARAMETERS = {"name": "list_parameters", "ros_service": "/sim_robot/list_parameters",
                   "ros_type": "rcl_interfaces/srv/ListParameters", "read_only": True, "timeout": 5.0}
# A camera whose rule sends the image file itself (encoding: raw), and a scan sent as CBOR, which the page
# cannot decode and must say so: nothing here publishes them on ROS; the test plays turtle1's MQTT side.
RAW_CAMERA = {"direction": "ros_to_mqtt", "ros_topic": "camera/compressed",
              "ros_type": "sensor_msgs/msg/CompressedImage", "mqtt_topic": "state/camera", "encoding": "raw"}
CBOR_SCAN = {"direction": "ros_to_mqtt", "ros_topic": "scan_cbor", "ros_type": "sensor_msgs/msg/LaserScan",
             "mqtt_topic": "state/scan_cbor", "encoding": "cbor"}


def _fleet_file(work: Path) -> Path:
    """config/robots.yaml with LIST_PARAMETERS added to turtle1's services (broker and bridge read this copy)."""
    import yaml

    fleet = yaml.safe_load(CONFIG.read_text())
    turtle1 = fleet["robots"]["turtle1"]
    turtle1["services"] = [*turtle1["services"], LIST_PARAMETERS]
    turtle1["rules"] = [*turtle1["rules"], RAW_CAMERA, CBOR_SCAN]
    path = work / "robots.yaml"
    path.write_text(yaml.safe_dump(fleet, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def stack(tmp_path_factory) -> Iterator[dict[str, Any]]:
    """Broker (TCP + WebSocket), sim, bridge, a ROS probe and the dashboard server; yielded once turtle1 is active."""
    from geometry_msgs.msg import PoseStamped, Twist
    from nav_msgs.msg import Odometry

    work = tmp_path_factory.mktemp("dashboard")
    config = _fleet_file(work)
    with live_robot(work, "embedded", fleet=config, ws=True) as live:
        probe = RosProbe()
        server = None
        try:
            cmd_vel = probe.watch(Twist, "/cmd_vel")
            odom = probe.watch(Odometry, "/odom")
            goals = probe.watch(PoseStamped, "/goal_pose")
            server = DashboardServer("127.0.0.1", 0, ws_port=live.ws_port).start()
            yield {"broker": live.server, "bridge": live.bridge, "cmd_vel": cmd_vel, "odom": odom, "goals": goals,
                   "url": server.url, "work": work, "probe": probe}
        finally:
            if server is not None:
                server.stop()
            probe.close()


# -- the browser: tests/support/browser.py ---------------------------------------------------------------------








def pose(driver: Any) -> tuple[float, float, int] | None:
    """The page's position readout (x, y, count of global_motion messages drawn), None before the first."""
    d = driver.execute_script("const p = document.getElementById('pose').dataset; return [p.x, p.y, p.n];")
    return None if d[0] is None else (float(d[0]), float(d[1]), int(d[2]))




def errors_text(driver: Any) -> str:
    return driver.execute_script("return document.getElementById('errors').textContent")


def moving(watch: Watch, since: float) -> list[Any]:
    """Non-zero twists that reached /cmd_vel after ``since``."""
    return [m for _, m in watch.since(since) if abs(m.linear.x) > 1e-6 or abs(m.angular.z) > 1e-6]


def wait_still(cmd_vel: Watch, quiet: float = 1.2, timeout: float = 15.0) -> None:
    """Until no non-zero twist has reached /cmd_vel for ``quiet`` s: earlier streams and stops are over."""
    wait_until(f"no motion command on /cmd_vel for {quiet:g} s (the robot kept receiving them)",
               lambda: not moving(cmd_vel, time.monotonic() - quiet), timeout=timeout, period=0.1)


def odom_xy(odom: Watch) -> tuple[float, float]:
    _, msg = odom.wait_for(lambda m: True, timeout=5, after=time.monotonic() - 0.5)
    return msg.pose.pose.position.x, msg.pose.pose.position.y


def hold(driver: Any, element_id: str) -> Any:
    """Press and keep pressing ``element_id`` (mouse down, no up); returns the ActionChains to release with."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    button = driver.find_element(By.ID, element_id)
    ActionChains(driver).click_and_hold(button).perform()
    return button


def release(driver: Any, button: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(driver).release(button).perform()




def alice_ready(driver: Any, stack: dict[str, Any]) -> None:
    """alice logged in, turtle1 online and selected, her operator controls shown, her presence published."""
    login(driver, stack["url"], "alice", "alice-demo")
    logged_in(driver, "alice")
    wait_until("turtle1 online", lambda: (robot_row(driver, "turtle1") or {}).get("presence") == "online")
    wait_until("alice's operator controls", lambda: visible(driver, "controls") and visible(driver, "estop"))
    wait_until("alice's presence heartbeat", lambda: driver.execute_script(
        "return window.dashboard.presenceTimer !== null"))


def arm_if_blocked(stack: dict[str, Any]) -> None:
    """A test that leaves turtle1 e-stopped must not break the next one: arm it over plain MQTT, until the robot's
    retained state/control says motion is not blocked (at once when it was not)."""
    with TestClient(stack["broker"].port, "alice", "alice-demo", operator=True) as alice:
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/state/control")
        alice.publish("roslink/turtle1/from/alice/cmd/arm", {"message_id": 104, "payload": {}})
        try:
            alice.wait_for(lambda m: m.topic.endswith("/state/control") and bool(m.payload)
                           and not ControlState.from_json(m.payload).blocked, timeout=10)
        except TimeoutError:  # (called in `finally`: the test's own failure is the one to see)
            print("arm_if_blocked: turtle1 still blocked 10 s after alice's arm")


# -- the tests -------------------------------------------------------------------------------------------------

def test_alice_sees_turtle1_and_drives_it_with_the_pad(stack, tmp_path) -> None:
    cmd_vel, odom = stack["cmd_vel"], stack["odom"]
    with browser(tmp_path, "drive") as driver:
        alice_ready(driver, stack)
        row = robot_row(driver, "turtle1")
        assert row["status"] == "active" and row["role"] == "operator" and row["session"].startswith("since "), row
        assert "%" in row["battery"] and row["mode"] == "MANUAL", row
        first = wait_until("a position on the plot", lambda: pose(driver))
        wait_until("live positions", lambda: (pose(driver) or (0, 0, 0))[2] >= first[2] + 5)
        wait_still(cmd_vel)
        x0, y0 = odom_xy(odom)

        t_press = time.monotonic()
        button = hold(driver, "drive-fwd")
        try:
            _, twist = cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=t_press)
            assert twist.linear.x == pytest.approx(0.3) and twist.angular.z == 0.0
            # 10 Hz while held: a stream, more than the page's one first command (waited for, not slept on)
            wait_until("ten twists streamed while held", lambda: len(
                [m for _, m in cmd_vel.since(t_press) if m.linear.x > 0.1]) >= 10, timeout=5)
            # held ~1.5 s in all (the distance checked below), and no stop meanwhile (the failsafe would send one)
            stays("no stop while the pad is held", lambda: not [m for _, m in cmd_vel.since(t_press)
                                                                if m.linear.x == 0.0 and m.angular.z == 0.0],
                  seconds=max(0.0, t_press + 1.5 - time.monotonic()), period=0.1)
            page_moved = wait_until("the plot's position to change", lambda: (
                (p := pose(driver)) and math.hypot(p[0] - first[0], p[1] - first[1]) > 0.2 and p))
        finally:
            # the clock is read before the release: the page's one zero twist can reach /cmd_vel before
            # Selenium's release() returns, and it is the only one (a zero twist ends the stream: no failsafe)
            t_release = time.monotonic()
            release(driver, button)
        stopped_at, stop = cmd_vel.wait_for(lambda m: m.linear.x == 0.0 and m.angular.z == 0.0, timeout=2,
                                            after=t_release)
        # nothing moves the robot after the release's zero reached it (a twist sent just before the release may
        # arrive after the release on a busy machine, but never after the zero)
        never("motion after the release's stop", lambda: [
            m for at, m in cmd_vel.since(t_release) if at > stopped_at and (m.linear.x or m.angular.z)][:3],
            seconds=0.5)
        x1, y1 = odom_xy(odom)
        travelled = math.hypot(x1 - x0, y1 - y0)
        assert 0.3 < travelled < 1.5, (x0, y0, x1, y1)  # ~0.3 m/s for ~1.6 s on the ROS side
        print(f"\npad forward: robot moved {travelled:.2f} m on /odom; page showed {page_moved}; released → "
              f"zero twist after {(cmd_vel.since(t_release)[0][0] - t_release) * 1000:.0f} ms")

        # keyboard: ↑ held drives, key-up stops
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.keys import Keys

        wait_still(cmd_vel)
        t_key = time.monotonic()
        ActionChains(driver).key_down(Keys.ARROW_UP).perform()
        try:
            cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=t_key)
        finally:
            t_up = time.monotonic()  # before the key-up, as t_release above
            ActionChains(driver).key_up(Keys.ARROW_UP).perform()
        up_stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0.0, timeout=2, after=t_up)
        # as for the pad: a twist sent just before the key-up may land after it, never after its zero
        never("motion after the key-up's stop", lambda: [
            m for at, m in cmd_vel.since(t_up) if at > up_stopped_at and (m.linear.x or m.angular.z)][:3], seconds=0.5)

        # the page's MQTT client object, used from the console, reaches the robot for an operator (the
        # positive control of the viewer test below)
        wait_still(cmd_vel)
        t_console = time.monotonic()
        driver.execute_script("""
            const d = window.dashboard;
            d.client.publish(`roslink/turtle1/from/${d.user}/cmd/twist`, JSON.stringify({lx: 0.21}));""")
        cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.21), timeout=3, after=t_console)

        # a service button built from alice's access report
        from selenium.webdriver.common.by import By

        driver.find_element(By.CSS_SELECTOR, '#services button[data-service="reset"]').click()
        wait_until("the reset reply", lambda: driver.execute_script(
            "return document.getElementById('service-result').dataset.result") == "ok")
        assert "pose reset" in driver.find_element(By.ID, "service-result").text
        wait_until("the plot back at the centre", lambda: (p := pose(driver)) and math.hypot(p[0], p[1]) < 0.05)
        rates = driver.execute_script("""
            const out = {};
            for (const tr of document.querySelectorAll('#rates tbody tr')) out[tr.dataset.topic] = +tr.dataset.hz;
            return out;""")
        assert 6 <= rates.get("global_motion", 0) <= 14 and 2 <= rates.get("range_finder_data", 0) <= 8, rates
        uplink = wait_until("the uplink line (state/link)", lambda: driver.find_element(By.ID, "uplink").text)
        assert uplink.startswith("uplink ") and "kbit/s" in uplink and " — " in uplink, uplink
        scan_drawn = driver.execute_script("return window.dashboard.robots.get('turtle1').scan.ranges.length")
        assert scan_drawn == 360
        wait_until("the GPS panel", lambda: visible(driver, "gps-box"))
        gps_text = driver.find_element(By.ID, "gps-text").text
        assert "fix 3D" in gps_text and "sats –" in gps_text, gps_text  # NavSatFix reports no satellite count: not 0
        session = (robot_row(driver, "turtle1") or {}).get("session", "")
        assert session.startswith("since ") and ":" in session, session  # the bridge's start, as a time of day

        # click on the plot: a go-to-waypoint reaches ROS as a goal pose
        goals = stack["goals"]
        driver.find_element(By.ID, "waypoint-mode").click()
        plot = driver.find_element(By.ID, "plot")
        t_click = time.monotonic()
        ActionChains(driver).move_to_element_with_offset(plot, 140, -140).click().perform()  # right of, above centre
        _, goal = goals.wait_for(lambda m: True, timeout=5, after=t_click)
        assert goal.pose.position.x > 1.0 and goal.pose.position.y > 1.0, goal.pose.position
        # the plot shows the marker (set by the click) and the trail once a frame is drawn after it
        wait_until("the waypoint on the plot", lambda: driver.execute_script(
            "return window.dashboard.waypoint !== null"))
        driver.execute_async_script("const done = arguments[0]; requestAnimationFrame(() => requestAnimationFrame("
                                    "() => done()))")
        shot = tmp_path / "dashboard-drive.png"
        driver.save_screenshot(str(shot))
        print(f"screenshot: {shot}")
        no_console_errors(driver)

        # Log out: the page signs off and clears its retained presence heartbeat (no stale operator left behind)
        client_id = driver.execute_script("return window.dashboard.clientId")
        presence = f"roslink/operators/alice/{client_id}"
        with TestClient(stack["broker"].port, "admin", "admin-demo") as admin:
            assert admin.connect() == 0
            admin.subscribe(presence)
            assert admin.wait_for(lambda m: m.topic == presence, timeout=3).payload  # retained, live
            driver.find_element(By.ID, "logout").click()
            wait_until("the login form again", lambda: visible(driver, "login") and not visible(driver, "estop"))
            admin.wait_for(lambda m: m.topic == presence and m.payload == b"", timeout=3)
        with TestClient(stack["broker"].port, "admin", "admin-demo") as late:
            assert late.connect() == 0
            late.subscribe(presence)
            assert [m for m in late.drain(0.5) if m.payload] == [], "a retained heartbeat outlived the logout"


def test_emergency_stop_latches_until_resume(stack, tmp_path) -> None:
    from selenium.webdriver.common.by import By

    cmd_vel = stack["cmd_vel"]
    try:
        with browser(tmp_path, "estop") as driver:
            alice_ready(driver, stack)
            wait_still(cmd_vel)
            button = hold(driver, "drive-fwd")
            t_press = time.monotonic()
            try:
                cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=t_press)
                t_stop = time.monotonic()
                driver.find_element(By.ID, "estop").click()  # while the pad is still held
            finally:
                release(driver, button)
            at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0.0 and m.angular.z == 0.0, timeout=2, after=t_stop)
            print(f"\ne-stop: zero twist {(at - t_stop) * 1000:.0f} ms after the click")
            wait_until("the blocked banner", lambda: visible(driver, "robot-banner") and "blocked" in
                       driver.find_element(By.ID, "robot-banner").text)
            assert (robot_row(driver, "turtle1") or {}).get("status") == "emergency"
            wait_until("the stop on the control line", lambda: "EMERGENCY STOP (emergency stop by alice)" in
                       driver.find_element(By.ID, "driver").text)  # where people look for who drives

            # latched: the pad's motion buttons are disabled (a press sends nothing), and a twist sent anyway (from
            # the console) is refused by the robot, which the page says
            wait_until("the pad disabled", lambda: driver.execute_script(
                "return [...document.querySelectorAll('.pad button')].every(b => b.disabled === "
                "(b.dataset.dir !== 'stop'))"))
            t_try = time.monotonic()
            button = hold(driver, "drive-fwd")
            never("motion from the disabled pad", lambda: moving(cmd_vel, t_try)[:3], seconds=0.5)
            release(driver, button)
            assert driver.execute_script("return document.getElementById('driving').dataset.driving") == "no"
            driver.execute_script("window.dashboard.sendTwist('turtle1', 0.3, 0)")
            never("motion after the emergency stop", lambda: moving(cmd_vel, t_try)[:3], seconds=0.3)
            refusal = wait_until("the refusal in the page", lambda: "emergency stop by alice" in errors_text(driver)
                                 and errors_text(driver))
            assert "send cmd/arm to resume" in refusal
            assert "emergency stop by alice" in driver.find_element(By.ID, "notice").text

            # Resume (arm) clears it: the red refusal line goes, the pad is enabled, the same press drives again
            driver.find_element(By.ID, "arm").click()
            wait_until("turtle1 active again", lambda: (robot_row(driver, "turtle1") or {}).get("status") == "active")
            assert not visible(driver, "robot-banner")
            wait_until("the refusal line cleared, the pad enabled", lambda: not visible(driver, "notice") and
                       driver.execute_script("return !document.getElementById('drive-fwd').disabled"))
            t_again = time.monotonic()
            button = hold(driver, "drive-fwd")
            try:
                cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=t_again)
            finally:
                release(driver, button)
            assert (robot_row(driver, "turtle1") or {}).get("owner", "").startswith("alice since")  # she drives
            _take_over_and_stop_all(driver, stack)
    finally:
        arm_if_blocked(stack)


RECT = "const r = document.getElementById(arguments[0]).getBoundingClientRect(); " \
       "return {top: r.top, bottom: r.bottom, left: r.left, right: r.right, height: r.height};"


def _overlap(a: dict, b: dict) -> bool:
    return a["left"] < b["right"] and b["left"] < a["right"] and a["top"] < b["bottom"] and b["top"] < a["bottom"]


@pytest.mark.parametrize("width", [400, 1280])
def test_nothing_moves_under_the_pad_and_a_phone_fits(stack, tmp_path, width: int) -> None:
    """At 400×800 (a phone) and 1280×800: the e-stop stops the robot (a zero twist within ESTOP_DEADLINE of the
    click) and covers neither the connection state nor Log out and sits in
    the window; the page never scrolls sideways; the pad's buttons are thumb-sized on a phone; and when the
    blocked banner and a red refusal line appear (an e-stop, then a twist the robot refuses) the drive pad stays
    exactly where it was: nothing jumps under a held finger."""
    from selenium.webdriver.common.by import By

    try:
        with browser(tmp_path, f"layout-{width}") as driver:
            driver.set_window_size(width, 800)
            alice_ready(driver, stack)
            inner = driver.execute_script("return [window.innerWidth, window.innerHeight]")
            assert inner[0] <= width, inner
            estop = driver.execute_script(RECT, "estop")
            stops = driver.execute_script(RECT, "stop-all")
            for other in ("conn", "logout", "whoami", "tab-fleet", "tab-robot"):
                for button, rect in (("e-stop", estop), ("STOP ALL", stops)):
                    assert not _overlap(rect, driver.execute_script(RECT, other)), f"the {button} covers #{other}"
            assert 0 <= estop["top"] and estop["bottom"] <= inner[1], estop
            assert driver.execute_script("return document.documentElement.scrollWidth") <= inner[0] + 1
            if width <= 640:
                assert driver.execute_script(RECT, "drive-fwd")["height"] >= 44  # a thumb's width (WCAG: 44 px)
            # every parameter's box and Set button within the window (at 400 px the table was 492 px wide, and
            # the page does not scroll sideways: they could not be reached)
            wait_until("the parameter rows", lambda: driver.execute_script(
                "return document.querySelectorAll('.param-table tr input').length") > 0)
            outside = driver.execute_script(
                "return [...document.querySelectorAll('.param-table input, .param-table button')]"
                ".map(e => e.getBoundingClientRect()).filter(r => r.left < -1 || r.right > window.innerWidth + 1)"
                ".length")
            assert outside == 0, f"{outside} parameter controls outside the {inner[0]} px window"
            driver.execute_script("document.getElementById('drive-fwd').scrollIntoView({block: 'center'})")
            before = driver.execute_script(RECT, "drive-fwd")["top"]
            # the e-stop, pressed while driving at this width: a zero twist on /cmd_vel within ESTOP_DEADLINE
            cmd_vel = stack["cmd_vel"]
            wait_still(cmd_vel)
            button = hold(driver, "drive-fwd")
            try:
                cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=time.monotonic())
                t_click = time.monotonic()
                driver.find_element(By.ID, "estop").click()
            finally:
                release(driver, button)
            at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0.0 and m.angular.z == 0.0, timeout=2, after=t_click)
            record_measurement(f"dashboard: e-stop click → zero twist ({width} px)", at - t_click, ESTOP_TARGET)
            assert at - t_click < ESTOP_DEADLINE, f"zero twist {(at - t_click) * 1000:.0f} ms after the click"
            wait_until("the blocked banner", lambda: visible(driver, "robot-banner"))
            driver.execute_script("window.dashboard.sendTwist('turtle1', 0.3, 0)")
            wait_until("the red refusal line", lambda: visible(driver, "notice"))
            notice = driver.execute_script(RECT, "notice")
            for other in ("conn", "logout", "estop"):
                assert not _overlap(notice, driver.execute_script(RECT, other)), f"the red line covers #{other}"
            after = driver.execute_script(RECT, "drive-fwd")["top"]
            assert abs(after - before) < 1, f"the pad moved {after - before:.0f} px when the banners came"
            assert driver.execute_script("return document.documentElement.scrollWidth") <= inner[0] + 1
            no_console_errors(driver)
            if os.environ.get("DASHBOARD_SCREENSHOT_DIR"):
                driver.save_screenshot(str(Path(os.environ["DASHBOARD_SCREENSHOT_DIR"]) / f"dashboard-{width}.png"))
    finally:
        arm_if_blocked(stack)


def _take_over_and_stop_all(driver: Any, stack: dict[str, Any]) -> None:
    """Another operator drives: the pad refuses with the holder's name; Take over (after the confirmation) moves
    control and tells the old driver; STOP ALL reports each robot's acknowledgement."""
    from selenium.webdriver.common.by import By

    with TestClient(stack["broker"].port, "admin", "admin-demo", operator=True) as admin:
        assert admin.connect() == 0
        admin.subscribe("roslink/turtle1/to/admin/error")
        admin.publish("roslink/turtle1/from/admin/control/take_over", b"")  # admin takes it from alice's page
        wait_until("admin drives, says the page", lambda: (robot_row(driver, "turtle1") or {}).get(
            "owner", "").startswith("admin since") and visible(driver, "take-over"))
        assert "driven by admin since" in driver.find_element(By.ID, "driver").text
        assert "taken over by admin from alice" in errors_text(driver)  # told at once, on her error topic
        assert driver.execute_script("return window.dashboard.sendTwist('turtle1', 0.2, 0)") is False
        assert "turtle1 is driven by admin since" in errors_text(driver)

        driver.find_element(By.ID, "take-over").click()
        alert = driver.switch_to.alert
        assert "Take control of turtle1 from admin?" in alert.text
        alert.accept()
        told = admin.wait_for(lambda m: "taken over by alice from admin" in m.json().get("error", ""), timeout=5)
        assert told.json()["topic"] == "roslink/turtle1/state/control"
        wait_until("alice drives again", lambda: (robot_row(driver, "turtle1") or {}).get("owner", "").startswith(
            "alice since") and not visible(driver, "take-over"))

    # explicit release and claim: the buttons follow who holds control
    driver.find_element(By.ID, "release").click()
    wait_until("released", lambda: (robot_row(driver, "turtle1") or {}).get("owner") == "–"
               and visible(driver, "claim") and not visible(driver, "release"))
    assert "nobody drives it" in driver.find_element(By.ID, "driver").text
    driver.find_element(By.ID, "claim").click()
    wait_until("claimed", lambda: (robot_row(driver, "turtle1") or {}).get("owner", "").startswith("alice since")
               and visible(driver, "release") and not visible(driver, "claim"))

    driver.find_element(By.ID, "stop-all").click()
    acked = wait_until("STOP ALL's report", lambda: "turtle1 stopped (acknowledged in" in driver.find_element(
        By.ID, "acks").text and driver.find_element(By.ID, "acks").text)
    assert "NOT ACKNOWLEDGED" not in acked
    assert driver.execute_script("return document.getElementById('stop-all').dataset.result") == "acknowledged"
    wait_until("turtle1 stopped", lambda: (robot_row(driver, "turtle1") or {}).get("status") == "emergency")
    no_console_errors(driver)


def _browser_pids(driver: Any) -> list[int]:
    """Chromium's main process(es): the children of chromedriver (read from /proc, no extra package)."""
    root = driver.service.process.pid
    children: list[int] = []
    for task in Path(f"/proc/{root}/task").iterdir():
        children += [int(p) for p in (task / "children").read_text().split()]
    return children


@pytest.mark.parametrize("how", ["quit", "kill"])
def test_closing_the_page_while_driving_stops_the_robot(stack, tmp_path, how) -> None:
    """``quit``: the browser closes (the page may still sign off); ``kill``: SIGKILL, only the last-will is left."""
    import signal

    cmd_vel = stack["cmd_vel"]
    with browser(tmp_path, f"close-{how}") as driver:
        alice_ready(driver, stack)
        wait_still(cmd_vel)
        pids = _browser_pids(driver)
        assert pids, "no chromium process under chromedriver"
        t_press = time.monotonic()
        hold(driver, "drive-fwd")
        cmd_vel.wait_for(lambda m: m.linear.x > 0.1, timeout=5, after=t_press)
        # mid-stream: the page keeps sending at 10 Hz while the button is held (the first twist and 0.5 s more)
        wait_until("six twists of the page's stream", lambda: len(
            [m for _, m in cmd_vel.since(t_press) if m.linear.x > 0.1]) >= 6, timeout=10)
        t_close = time.monotonic()
        if how == "quit":
            driver.quit()  # the whole browser goes, with the button still held
        else:
            for pid in pids:
                os.kill(pid, signal.SIGKILL)  # no pagehide, no sign-off: the kernel closes the WebSocket
    closed = time.monotonic()
    at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0.0 and m.angular.z == 0.0, timeout=FAILSAFE_BOUND + 3,
                             after=t_close)
    elapsed = at - t_close
    print(f"\npage closed ({how}) while driving: zero twist on /cmd_vel {elapsed * 1000:.0f} ms after closing "
          f"began (closing took {(closed - t_close) * 1000:.0f} ms; failsafe bound {FAILSAFE_BOUND:g} s)")
    never("motion after the stop", lambda: moving(cmd_vel, at + 0.2)[:3], seconds=1.0)
    assert elapsed <= FAILSAFE_BOUND, f"stopped only after {elapsed:.2f} s"
    from tests.support.measure import record_measurement

    record_measurement(f"dashboard: page closed ({how}) while driving → stop", elapsed, FAILSAFE_BOUND)


def test_bob_sees_turtle1_without_controls_and_cannot_command_it(stack, tmp_path) -> None:
    from selenium.webdriver.common.by import By

    cmd_vel = stack["cmd_vel"]
    with browser(tmp_path, "bob") as driver:
        login(driver, stack["url"], "bob", "bob-demo")
        logged_in(driver, "bob")
        wait_until("turtle1 online", lambda: (robot_row(driver, "turtle1") or {}).get("presence") == "online")
        wait_until("bob's role", lambda: (robot_row(driver, "turtle1") or {}).get("role") == "viewer")
        wait_until("a position on the plot", lambda: pose(driver))
        assert not visible(driver, "controls") and not visible(driver, "waypoint-label")
        # any granted user may stop a robot: bob gets the emergency stop (and STOP ALL), nothing else
        wait_until("bob's emergency stop", lambda: visible(driver, "estop") and visible(driver, "stop-all"))
        # of the services only the read-only one his access report lists: no `reset`
        wait_until("bob's read-only service", lambda: driver.find_elements(
            By.CSS_SELECTOR, '#services form[data-service="list_parameters"]'))
        assert visible(driver, "services-box")
        assert not driver.find_elements(By.CSS_SELECTOR, '#services [data-service="reset"]')
        assert "viewer of turtle1" in driver.find_element(By.ID, "viewer-note").text
        assert not any(b.is_displayed() for b in driver.find_elements(By.CSS_SELECTOR, ".pad button, #arm"))
        wait_still(cmd_vel)

        # The page's own command path refuses, visibly.
        assert driver.execute_script("return window.dashboard.sendTwist('turtle1', 0.37, 0)") is False
        assert "bob is a viewer of turtle1" in errors_text(driver)
        # The console: the page's MQTT client publishing by hand, with a presence heartbeat first, a bare twist
        # and a service call: the broker's ACL drops them before they reach the robot. His emergency stop it lets
        # through (any granted user may stop a robot), and nothing he sends can resume the robot.
        t0 = time.monotonic()
        driver.execute_script("""
            const d = window.dashboard, c = d.client;
            const hb = JSON.stringify({message_id: 0, payload: {type: 0, name: d.clientId, system_status: 4,
                                       owner_id: 'bob', mode: 0}});
            c.publish(`roslink/operators/bob/${d.clientId}`, hb, {retain: true});
            for (let i = 0; i < 10; i++) c.publish('roslink/turtle1/from/bob/cmd/twist', JSON.stringify({lx: 0.37}));
            c.publish('roslink/turtle1/from/alice/cmd/twist', JSON.stringify({lx: 0.37}));
            c.publish('roslink/turtle1/from/bob/cmd/emergency_stop', JSON.stringify({reason: 'bob'}), {qos: 1});
            c.publish('roslink/turtle1/from/bob/call/reset', JSON.stringify({id: 'b1', args: {}}), {qos: 1});
            c.publish('roslink/turtle1/from/bob/cmd/arm', JSON.stringify({}), {qos: 1});""")
        # the page shows the stop with turtle1's next heartbeat (once a second): waited for, not slept on
        wait_until("bob's e-stop shown", lambda: (robot_row(driver, "turtle1") or {}).get("status") == "emergency",
                   timeout=5)
        # bob's twists were sent before his stop: had any passed the ACL it would be here by now
        never("bob's twist reaching ROS", lambda: [m for _, m in cmd_vel.since(t0)
                                                   if m.linear.x == pytest.approx(0.37)], seconds=0.5)
        arm_if_blocked(stack)
        assert driver.execute_script("return document.getElementById('conn').dataset.state") == "connected"

        # A camera image, when the robot maps one, is shown to viewers too (played here as turtle1's state/image:
        # the demo fleet maps no camera). A 1×1 PNG.
        png = ("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8BQDwAEhQGAhKmMIQAAAABJRU5ErkJggg==")
        with TestClient(stack["broker"].port, "turtle1", "turtle1-demo") as robot:
            assert robot.connect() == 0
            robot.publish("roslink/turtle1/state/image", {"message_id": 5, "system_id": 1, "payload": {
                "time_usec": 0, "width": 1, "height": 1, "format": "png", "data": png}})
            wait_until("the camera image", lambda: visible(driver, "camera-box") and driver.execute_script(
                "const i = document.getElementById('camera'); return i.complete && i.naturalWidth === 1"))
            # the same PNG as a raw-encoded camera (the file itself), then a CBOR scan the page cannot show
            robot.publish("roslink/turtle1/state/camera", base64.b64decode(png))
            wait_until("the raw camera image", lambda: driver.execute_script(
                "const i = document.getElementById('camera'); return i.dataset.state === 'camera' && "
                "i.src.startsWith('blob:') && i.complete && i.naturalWidth === 1"))
            robot.publish("roslink/turtle1/state/scan_cbor", b"\xa1\x61a\x01")
            wait_until("the undecodable CBOR state said so", lambda: "state/scan_cbor is cbor" in driver.find_element(
                By.ID, "errors").text)
        no_console_errors(driver)
        driver.execute_script("window.dashboard.client.publish(`roslink/operators/bob/${window.dashboard.clientId}`,"
                              " '', {retain: true, qos: 1})")


def _canvas_floor(driver: Any) -> list[int]:
    """The video canvas's pixels along a row of the floor (the lower quarter), as RGB values."""
    return driver.execute_script("""
        const c = document.getElementById('video-canvas');
        const row = Math.floor(c.height * 0.8);
        return Array.from(c.getContext('2d').getImageData(0, row, c.width, 1).data)
            .filter((_, i) => i % 4 !== 3);""")


def test_bob_watches_turtle1s_camera_decoded_by_the_browser(stack, tmp_path) -> None:
    """bob (a viewer) clicks Watch: the robot's H.264 frames are decoded by Chromium's WebCodecs onto the canvas,
    the floor on it moves as alice turns the robot, and Stop watching ends the stream (the robot stops sending)."""
    from roslink_mqtt.client import RobotClient

    with browser(tmp_path, "video") as driver:
        login(driver, stack["url"], "bob", "bob-demo")
        logged_in(driver, "bob")
        wait_until("the video panel", lambda: visible(driver, "video-box"), timeout=30)
        asked = time.monotonic()
        driver.find_element("id", "video-watch").click()
        wait_until("ten pictures on the canvas", lambda: int(driver.execute_script(
            "return document.getElementById('video-canvas').dataset.frames || '0'")) >= 10, timeout=60)
        record_measurement("dashboard video: Watch → ten pictures decoded by the browser", time.monotonic() - asked,
                           60.0)
        age = int(driver.execute_script("return document.getElementById('video-canvas').dataset.age"))
        record_measurement("dashboard video: a picture's age when drawn (loopback)", age / 1000, 5.0)
        before = _canvas_floor(driver)
        with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{stack['broker'].port}") as alice:
            alice.wait_for_robot("turtle1")
            for _ in paced(0.1, count=10):  # turn in place for a second: the tiles slide across the picture
                alice.twist("turtle1", az=1.0)
            alice.twist("turtle1")
        # the tiles slide past: most of the row changes by far more than an encoder's noise (a few levels)
        wait_until("the floor to move on the canvas", lambda: sum(
            abs(a - b) > 40 for a, b in zip(_canvas_floor(driver), before, strict=False)) > len(before) // 10,
            timeout=10)
        assert "fps" in driver.find_element("id", "video-stats").text
        driver.find_element("id", "video-watch").click()  # stop watching
        wait_until("the watch ended", lambda: driver.execute_script("return window.dashboard.video === null"))
        no_console_errors(driver)


def test_a_snapshot_from_the_page_is_the_robots_own_mcap_file(stack, tmp_path) -> None:
    """alice's "Save the last 30 s" (her access report says she may): the chunks are joined, the SHA-256 checked,
    the file offered as a download; it is the robot's MCAP (ros2 profile, odom and scan as CDR). bob gets no
    button (a viewer, and turtle1's snapshot.who is operators)."""
    import io

    from mcap.reader import make_reader

    with browser(tmp_path, "snapshot") as driver:
        alice_ready(driver, stack)
        wait_until("the snapshot button", lambda: visible(driver, "snapshot-box"))
        driver.find_element("id", "snapshot").click()
        state = wait_until("the snapshot saved", lambda: (s := driver.execute_script(
            "return document.getElementById('snapshot-status').dataset.state")) in ("saved", "failed", "refused")
            and s, timeout=30)
        text = driver.find_element("id", "snapshot-status").text
        assert state == "saved" and "SHA-256 checked" in text, text
        data = base64.b64decode(driver.execute_script("""
            const snap = [...window.dashboard.snapshots.values()].pop();
            let s = ""; for (const b of snap.file) s += String.fromCharCode(b); return btoa(s);"""))
        no_console_errors(driver)
    reader = make_reader(io.BytesIO(data))
    assert reader.get_header().profile == "ros2"
    summary = reader.get_summary()
    assert summary is not None and {c.topic for c in summary.channels.values()} >= {"odom", "scan"}
    assert summary.statistics is not None and summary.statistics.message_count > 20
    with browser(tmp_path, "snapshot-bob") as driver:
        login(driver, stack["url"], "bob", "bob-demo")
        logged_in(driver, "bob")
        wait_until("turtle1 shown to bob as its viewer", lambda: visible(driver, "viewer-note") and "viewer of turtle1"
                   in driver.find_element("id", "viewer-note").text)
        assert not visible(driver, "snapshot-box")


def test_the_plot_zooms_pans_follows_and_the_inspector_shows_a_topic(stack, tmp_path) -> None:
    """bob (a viewer: the plot is everyone's) zooms with the buttons and the wheel, pans by dragging (which is not
    a click), follows the robot and resets the view; the grid lines carry their metres; a click on a row of
    "Message rates" shows that topic's latest message, decoded, with its size, rate and age."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.common.by import By

    with browser(tmp_path, "plot") as driver:
        login(driver, stack["url"], "bob", "bob-demo")
        logged_in(driver, "bob")
        wait_until("a pose in the plot", lambda: driver.execute_script(
            "const r = window.dashboard.robots.get('turtle1'); return Boolean(r && r.pose)"))
        view = lambda: driver.execute_script("return {...window.dashboard.view}")  # noqa: E731
        labels = wait_until("axis labels", lambda: driver.find_element(By.ID, "plot").get_attribute("data-labels"))
        assert "x1" in labels.split() and "y1" in labels.split(), labels
        start = view()
        driver.find_element(By.ID, "plot-zoom-in").click()
        zoomed = view()
        assert zoomed["half"] == pytest.approx(start["half"] / 2) and zoomed["manual"]
        plot = driver.find_element(By.ID, "plot")
        ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(plot), 0, 120).perform()
        wait_until("the wheel zoomed out", lambda: view()["half"] == pytest.approx(zoomed["half"] * 1.25))
        before = view()
        ActionChains(driver).click_and_hold(plot).move_by_offset(60, 0).move_by_offset(60, 0).release().perform()
        panned = view()
        assert panned["cx"] < before["cx"] - 0.1 and panned["cy"] == pytest.approx(before["cy"], abs=0.05), panned
        driver.find_element(By.ID, "plot-follow").click()
        pose = driver.execute_script("return window.dashboard.robots.get('turtle1').pose")
        wait_until("the view on the robot", lambda: abs(view()["cx"] - pose["x"]) < 0.5 and
                   abs(view()["cy"] - pose["y"]) < 0.5)
        driver.find_element(By.ID, "plot-reset").click()
        reset = view()
        assert (reset["half"], reset["cx"], reset["cy"], reset["manual"], reset["follow"]) == (6, 0, 0, False, False) \
            or (reset["half"] >= 6 and not reset["manual"] and not reset["follow"]), reset
        assert not driver.find_element(By.ID, "plot-follow").is_selected()

        # the state inspector: a click on a row of "Message rates" shows that topic's latest message, decoded
        row = wait_until("the global_motion rate row", lambda: driver.find_elements(
            By.CSS_SELECTOR, '#rates tbody tr[data-topic="global_motion"]'))
        row[0].click()
        head = wait_until("the inspector", lambda: visible(driver, "inspector") and
                          driver.find_element(By.ID, "inspector-head").text)
        assert head.startswith("state/global_motion · json · ") and " Hz · " in head, head
        shown = json.loads(driver.find_element(By.ID, "inspector-body").text)
        assert shown["message_id"] == 2 and isinstance(shown["payload"]["x"], (int, float)), shown
        raw = driver.execute_script("return document.getElementById('inspector-raw').textContent")
        assert json.loads(raw)["message_id"] == 2 and "\n" not in raw, raw  # as it came: one line of JSON
        no_console_errors(driver)


def test_carol_does_not_see_turtle1_but_her_turtle2_online_stale_offline(stack, tmp_path) -> None:
    with browser(tmp_path, "carol") as driver:
        login(driver, stack["url"], "carol", "carol-demo")
        logged_in(driver, "carol")
        # retained heartbeats arrive right after SUBACK; live ones every second
        never("a robot shown to carol", lambda: robot_row(driver, "turtle1") or driver.execute_script(
            "return [...window.dashboard.robots.keys()]"), seconds=1.5, period=0.1)
        assert robot_row(driver, "turtle1") is None
        assert visible(driver, "fleet-empty")
        seen = driver.execute_script("return [...window.dashboard.robots.keys()]")
        assert seen == [], seen
        assert not visible(driver, "notice"), "carol's subscriptions were refused"

        # Her own turtle2 (no bridge runs: admin plays its heartbeat) appears online, goes stale when the beats
        # stop without a will, and offline on the bridge's last-will; no access report, so no controls.
        def heartbeat(status: int) -> dict[str, Any]:
            return {"message_id": 0, "system_id": 2, "payload": {"type": 1, "name": "turtle2", "system_status": status,
                                                                  "owner_id": "", "mode": 2, "session": 7}}

        with TestClient(stack["broker"].port, "admin", "admin-demo") as admin:
            assert admin.connect() == 0
            try:
                t_last = time.monotonic()  # before the heartbeat: the WebDriver calls below only add to the wait
                admin.publish("roslink/turtle2/heartbeat", heartbeat(4))
                row = wait_until("turtle2 online", lambda: (r := robot_row(driver, "turtle2")) and
                                 r["presence"] == "online" and r)
                assert row["session"] == "7" and row["mode"] == "GUIDED" and row["status"] == "active", row
                assert not visible(driver, "controls") and not visible(driver, "estop")
                assert "access report" in driver.find_element("id", "viewer-note").text
                stale = wait_until("turtle2 stale", lambda: (robot_row(driver, "turtle2") or {}).get("presence")
                                   == "stale", timeout=10)
                assert stale and time.monotonic() - t_last >= 4.5  # 5 s without a heartbeat
                admin.publish("roslink/turtle2/heartbeat", heartbeat(8), retain=True)
                wait_until("turtle2 offline", lambda: (robot_row(driver, "turtle2") or {}).get("presence") == "offline")
                assert robot_row(driver, "turtle1") is None
            finally:
                admin.publish("roslink/turtle2/heartbeat", b"", retain=True)  # leave no retained heartbeat behind
        wait_until("turtle2 gone with its cleared heartbeat", lambda: robot_row(driver, "turtle2") is None)


def test_wrong_password_is_refused_with_a_clear_message(stack, tmp_path) -> None:
    from selenium.webdriver.common.by import By

    with browser(tmp_path, "wrong-password") as driver:
        login(driver, stack["url"], "alice", "not-her-password")
        message = wait_until("the login error", lambda: visible(driver, "login-error")
                             and driver.find_element(By.ID, "login-error").text)
        print(f"\nwrong password: {message!r}")
        assert message == f"login refused: {WRONG_LOGIN}", message  # the words of the CLI and the SDK
        assert visible(driver, "login") and not visible(driver, "main")
        # no retry loop: the refusal is final until the user submits again
        stays("the login refusal", lambda: WRONG_LOGIN in driver.find_element(By.ID, "login-error").text,
              seconds=2.5, period=0.1)

        # an unknown user reads exactly the same (the broker never says which logins exist)
        driver.execute_script("document.getElementById('login-error').hidden = true")
        for field, text in (("username", "mallory"), ("password", "anything")):
            driver.find_element(By.ID, field).clear()
            driver.find_element(By.ID, field).send_keys(text)
        driver.find_element(By.ID, "connect").click()
        unknown = wait_until("the unknown user's login error", lambda: visible(driver, "login-error")
                             and driver.find_element(By.ID, "login-error").text)
        print(f"unknown user: {unknown!r}")
        assert unknown == message, unknown

        # a broker URL where nothing listens: said so, not a blank page
        from roslink_mqtt.localproc import free_port

        url = driver.find_element(By.ID, "ws-url")
        url.clear()
        url.send_keys(f"ws://127.0.0.1:{free_port()}")
        driver.find_element(By.ID, "password").clear()
        driver.find_element(By.ID, "password").send_keys("alice-demo")
        driver.find_element(By.ID, "connect").click()
        unreachable = wait_until("the unreachable message", lambda: "cannot reach the broker" in
                                 driver.find_element(By.ID, "login-error").text and
                                 driver.find_element(By.ID, "login-error").text)
        print(f"unreachable broker: {unreachable!r}")
        assert driver.find_element(By.ID, "connect").is_enabled()


def test_a_slow_login_answer_is_waited_for(tmp_path) -> None:
    """The broker's login throttle holds its answer after failed logins from an address (up to 10 s; an unknown
    user's login waits for the address's failures, having no known-good pair): the page waits for the verdict
    and says it is waiting, where it used to give up after 8 s with "connection error: connack timeout".

    A frozen broker of its own (SIGSTOP; the module's stack keeps running) holds the answer 4 s here.
    """
    import signal

    from selenium.webdriver.common.by import By

    with EmbeddedBrokerProcess(tmp_path, ws=True) as slow, browser(tmp_path, "slow-login") as driver:
        server = DashboardServer("127.0.0.1", 0, ws_port=slow.ws_port).start()
        try:
            driver.get(server.url)
            wait_until("the derived WebSocket URL", lambda: driver.find_element(By.ID, "ws-url").get_attribute("value"))
            driver.find_element(By.ID, "username").send_keys("mallory")
            driver.find_element(By.ID, "password").send_keys("a-guess")
            slow.signal(signal.SIGSTOP)
            try:
                driver.find_element(By.ID, "connect").click()
                clicked, said = time.monotonic(), []
                # the page says it waits after 3 s; that it waits LOGIN_WAIT (12 s, past the throttle's longest hold;
                # the page's old 8 s was not) is the generated constant's, checked in tests/unit/test_broker_urls.py

                def login_error() -> str | bool:
                    if visible(driver, "login-error"):
                        return driver.find_element(By.ID, "login-error").text or True
                    if "check the login" in (text := driver.find_element(By.ID, "conn").text):
                        said.append(text)
                    return False

                never("a login error while the broker holds its answer", login_error,
                      seconds=max(0.0, clicked + 4.0 - time.monotonic()), period=0.2)
                waiting = said[0] if said else ""
                print(f"\nwhile the broker holds its answer: {waiting!r}")
                assert waiting, "the page did not say that it waits for the broker's answer"
            finally:
                slow.signal(signal.SIGCONT)
            message = wait_until("the login error", lambda: visible(driver, "login-error")
                                 and driver.find_element(By.ID, "login-error").text)
            print(f"after {time.monotonic() - clicked:.1f} s: {message!r}")
            assert message == f"login refused: {WRONG_LOGIN}", message
        finally:
            server.stop()


def test_page_memory_stays_flat_while_the_robot_streams(stack, tmp_path) -> None:
    """~7 s of 10 Hz motion (the bridge's max_rate), 5 Hz scans and a moving robot: heap and DOM stay bounded.

    Samples are taken after a forced garbage collection (DevTools), so they measure what the page keeps, not
    what it has not collected yet. Another client drives turtle1 in a circle, so the trail and scan drawing
    run as in real use.
    """
    import threading

    with browser(tmp_path, "memory", precise_memory=True) as driver:
        alice_ready(driver, stack)
        wait_until("a position on the plot", lambda: pose(driver))
        driver.execute_cdp_cmd("Performance.enable", {})
        stop = threading.Event()

        def drive() -> None:
            with TestClient(stack["broker"].port, "alice", "alice-demo", operator=True) as op:
                assert op.connect() == 0
                seq = int(time.time() * 1000) % 2**32
                for _ in paced(0.1, count=300, stop=stop.is_set):  # bounded: at most 30 s at 10 Hz
                    seq += 1
                    op.publish("roslink/turtle1/from/alice/cmd/twist",
                               {"message_id": 100, "sequence_number": seq, "payload": {"lx": 0.3, "az": 0.6}}, qos=0)
                op.publish("roslink/turtle1/from/alice/cmd/twist", {"lx": 0.0}, qos=1)

        driver_thread = threading.Thread(target=drive, name="circle-driver", daemon=True)
        driver_thread.start()
        samples: list[tuple[float, float, int, int, int]] = []
        t0 = time.monotonic()
        try:
            for i in paced(1.4, count=6):  # every 1.4 s for 7 s, the first sample 1.4 s in
                if not i:
                    continue
                driver.execute_cdp_cmd("HeapProfiler.collectGarbage", {})
                heap = driver.execute_script("return performance.memory.usedJSHeapSize")
                dom = driver.execute_script("return document.getElementsByTagName('*').length")
                metrics = {m["name"]: m["value"]
                           for m in driver.execute_cdp_cmd("Performance.getMetrics", {})["metrics"]}
                n = (pose(driver) or (0, 0, 0))[2]
                samples.append((time.monotonic() - t0, heap / 1e6, dom, int(metrics.get("Nodes", -1)), n))
                if time.monotonic() - t0 > 10:
                    break
            shot = tmp_path / "dashboard.png"  # circles: trail, scan, rates (docs/dashboard.png)
            driver.save_screenshot(str(shot))
            print(f"\nscreenshot: {shot}")
            if os.environ.get("DASHBOARD_SCREENSHOT"):
                shutil.copy(shot, os.environ["DASHBOARD_SCREENSHOT"])
        finally:
            stop.set()
            driver_thread.join(10)
        print("\n   t s   heap MB   DOM elements   DOM nodes (incl. detached)   global_motion drawn")
        for t, heap, dom, nodes, n in samples:
            print(f"{t:6.1f}   {heap:7.2f}   {dom:12d}   {nodes:26d}   {n:19d}")
        first, last = samples[1], samples[-1]  # the first sample is still warm-up (lists filling, JIT)
        duration = last[0] - first[0]
        assert last[4] - first[4] >= 8 * duration, "the page stopped receiving positions"
        assert last[1] <= first[1] * 1.5 + 2.0, f"heap grew from {first[1]:.2f} MB to {last[1]:.2f} MB"
        assert last[2] <= first[2] + 80, f"DOM grew from {first[2]} to {last[2]} elements"
        assert last[3] <= first[3] + 400, f"DOM nodes grew from {first[3]} to {last[3]}"
        trail = driver.execute_script("return window.dashboard.robots.get('turtle1').trail.length")
        print(f"trail points kept: {trail}")
        assert 50 < trail <= 3000  # model.mjs TRAIL_MAX: kept while the page is open


# -- panels built from the robot description (services with arguments, actions, parameters) ------------------



def goal_panel(driver: Any, action: str = "fibonacci") -> dict[str, Any] | None:
    """What the page's action panel shows: status (data-status), goal id, feedback, result, progress, Cancel."""
    return driver.execute_script("""
        const p = document.querySelector(`.action[data-action="${arguments[0]}"]`);
        if (!p) return null;
        const s = p.querySelector('.goal-status'), f = p.querySelector('.goal-feedback');
        const pr = p.querySelector('.goal-progress');
        return {status: s.dataset.status, text: s.textContent, id: s.dataset.goalId || '',
                feedback: f.textContent, feedbacks: +(f.dataset.count || 0),
                result: p.querySelector('.goal-result').textContent,
                fraction: pr.hidden ? null : +pr.dataset.fraction,
                cancel: !p.querySelector('button.cancel').disabled};""", action)


def send_goal(driver: Any, order: str, action: str = "fibonacci", sent: bool = True) -> str:
    """Type ``order`` in the goal form and press Send; returns the new goal's id once the page shows it."""
    from selenium.webdriver.common.by import By

    before = (goal_panel(driver, action) or {}).get("id", "")
    field = driver.find_element(By.CSS_SELECTOR, f'form[data-action="{action}"] input[data-field="order"]')
    field.clear()
    field.send_keys(order)
    click(driver, driver.find_element(By.CSS_SELECTOR, f'form[data-action="{action}"] button.submit'))
    if not sent:
        return ""
    return wait_until("the goal in the panel", lambda: (g := goal_panel(driver, action)) and g["id"] != before
                      and g["id"], timeout=3)


def param_row(driver: Any, name: str, node: str = "sim_robot") -> dict[str, Any] | None:
    return driver.execute_script("""
        const tr = document.querySelector(`.params[data-params="${arguments[1]}"] tr[data-param="${arguments[0]}"]`);
        if (!tr) return null;
        return {value: tr.querySelector('.value').textContent, type: tr.dataset.type || '',
                edit: Boolean(tr.querySelector('input')), set: Boolean(tr.querySelector('button.set'))};""", name, node)


def param_result(driver: Any, node: str = "sim_robot") -> tuple[str, str]:
    r = driver.execute_script("""
        const e = document.querySelector(`.params[data-params="${arguments[0]}"] .param-result`);
        return e ? [e.dataset.result || '', e.textContent] : ['', ''];""", node)
    return r[0], r[1]


def ros_parameter(stack: dict[str, Any], name: str, node: str = "sim_robot") -> Any:
    """``name``'s value as the ROS node itself answers (its get_parameters service, called from the probe)."""
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import GetParameters

    client = stack.setdefault("get_parameters", stack["probe"].node.create_client(
        GetParameters, f"/{node}/get_parameters"))
    assert client.wait_for_service(timeout_sec=5), f"/{node}/get_parameters not available"
    future = client.call_async(GetParameters.Request(names=[name]))
    wait_until("the node's get_parameters answer", future.done, timeout=5, period=0.02)
    value = future.result().values[0]
    return {ParameterType.PARAMETER_DOUBLE: value.double_value, ParameterType.PARAMETER_INTEGER: value.integer_value,
            ParameterType.PARAMETER_BOOL: value.bool_value, ParameterType.PARAMETER_STRING: value.string_value,
            }.get(value.type)


def set_max_speed_over_mqtt(stack: dict[str, Any], value: float) -> None:
    """Put the sim's max_speed back (later tests drive it) without the page: alice's parameter set over MQTT."""
    with TestClient(stack["broker"].port, "alice", "alice-demo", operator=True) as alice:
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/to/alice/param_reply/sim_robot")
        time.sleep(0.3)  # the presence heartbeat first: setting needs a live operator
        alice.publish("roslink/turtle1/from/alice/param/sim_robot",
                      {"id": "restore", "op": "set", "values": {"max_speed": value}})
        reply = alice.wait_for(lambda m: m.json().get("id") == "restore", timeout=10).json()
        assert reply["result"] and reply["values"]["max_speed"]["successful"], reply


def test_alice_uses_the_service_form_action_panel_and_parameter_panel(stack, tmp_path) -> None:
    """One page for every check of issue 16's operator side (a browser and a login cost ~3 s each)."""
    from selenium.webdriver.common.by import By

    t_test = time.monotonic()
    with browser(tmp_path, "panels") as driver, \
            TestClient(stack["broker"].port, "admin", "admin-demo") as wire:
        assert wire.connect() == 0
        wire.subscribe("roslink/turtle1/from/alice/#")  # what the page really publishes
        alice_ready(driver, stack)
        form = wait_until("the list_parameters form", lambda: driver.find_elements(
            By.CSS_SELECTOR, '#services form[data-service="list_parameters"]'))[0]
        # a service without arguments stays one click
        assert driver.find_element(By.CSS_SELECTOR, '#services button[data-service="reset"]').is_displayed()

        # -- a service form validates on the page: nothing is published for a bad number or bad JSON
        depth = form.find_element(By.CSS_SELECTOR, 'input[data-field="depth"]')
        prefixes = form.find_element(By.CSS_SELECTOR, 'textarea[data-field="prefixes"]')
        assert depth.get_attribute("data-type") == "uint64" and prefixes.get_attribute("data-type") == "string[]"
        error = form.find_element(By.CSS_SELECTOR, ".form-error")
        wire.drain(0.3)
        for bad_depth, bad_prefixes, why in (("-1", "", "out of range for uint64"),
                                             ("2.5", "", "not an integer"),
                                             ("fast", "", 'depth: "fast" is not a number'),
                                             ("1", "sim", "prefixes: not JSON"),
                                             ("1", '"sim"', "expected a JSON array")):
            depth.clear()
            depth.send_keys(bad_depth)
            prefixes.clear()
            prefixes.send_keys(bad_prefixes)
            click(driver, form.find_element(By.CSS_SELECTOR, "button.submit"))
            shown = wait_until(f"the message for depth={bad_depth!r} prefixes={bad_prefixes!r}",
                               lambda: error.is_displayed() and error.text)
            assert why in shown and shown.startswith("not sent:"), shown
            assert form.get_attribute("data-state") == "invalid"
        never("an invalid form published", lambda: [(m.topic, m.payload) for m in wire.drain(0.01)
                                                     if "/call/" in m.topic], seconds=0.8)
        print(f"\nservice form: refused on the page: {error.text!r}")
        # the same form, valid: the call carries the typed arguments and the reply is shown
        depth.clear()
        depth.send_keys("0")
        prefixes.clear()
        prefixes.send_keys("[]")
        t_call = time.monotonic()
        click(driver, form.find_element(By.CSS_SELECTOR, "button.submit"))
        call = wire.wait_for(lambda m: m.topic.endswith("/call/list_parameters"), timeout=5).json()
        assert call["args"] == {"depth": 0, "prefixes": []}, call
        wait_until("the list_parameters reply", lambda: driver.execute_script(
            "return document.getElementById('service-result').dataset.result") == "ok")
        reply = driver.find_element(By.ID, "service-result").text
        assert "max_speed" in reply and "scan_beams" in reply, reply
        assert not error.is_displayed()
        print(f"service form: reply in {(time.monotonic() - t_call) * 1000:.0f} ms: {reply[:80]}…")

        # -- an action goal from the form: feedback, then the result
        panel = wait_until("the fibonacci panel", lambda: goal_panel(driver))
        assert panel["status"] == "idle" and not panel["cancel"], panel
        t_goal = time.monotonic()
        goal_id = send_goal(driver, "10")
        sent = wire.wait_for(lambda m: m.topic.endswith("/goal/fibonacci"), timeout=5).json()
        assert sent["id"] == goal_id and sent["goal"] == {"order": 10}, sent
        seen = wait_until("feedback in the panel", lambda: (g := goal_panel(driver))["feedbacks"] >= 1 and g)
        assert seen["feedback"].startswith("feedback: {\"sequence\":[0,1,1"), seen
        done = wait_until("the goal's result", lambda: (g := goal_panel(driver))["status"] not in (
            "sending", "accepted") and g, timeout=15)
        assert done["status"] == "succeeded", done
        assert done["result"] == 'result: {"sequence":[0,1,1,2,3,5,8,13,21,34,55]}', done
        assert done["fraction"] == 1.0 and not done["cancel"], done
        print(f"goal order 10: {done['feedbacks']} feedbacks shown, succeeded {time.monotonic() - t_goal:.2f} s "
              f"after Send")

        # -- order 41: the sim's action server rejects it, and the page says so (panel, error list, notice)
        send_goal(driver, "41")
        rejected = wait_until("the rejection", lambda: (g := goal_panel(driver))["status"] == "rejected" and g)
        assert "rejected" in rejected["text"] and not rejected["cancel"], rejected
        assert "rejected goal fibonacci" in errors_text(driver), errors_text(driver)
        assert "rejected goal fibonacci" in driver.find_element(By.ID, "notice").text
        print(f"goal order 41: {rejected['text']!r}")
        # an order that does not fit the form's int32 is refused on the page (nothing sent)
        wire.drain(0.2)
        send_goal(driver, "3000000000", sent=False)
        assert "out of range for int32" in driver.find_element(
            By.CSS_SELECTOR, 'form[data-action="fibonacci"] .form-error').text
        never("an out-of-range goal published", lambda: [(m.topic, m.payload) for m in wire.drain(0.01)
                                                         if "/goal/" in m.topic], seconds=0.5)

        # -- a long goal (order 40: ~3.9 s at 0.1 s a term) canceled from the page
        long_id = send_goal(driver, "40")
        wait_until("the long goal's progress", lambda: (g := goal_panel(driver))["feedbacks"] >= 2 and g["cancel"]
                   and g, timeout=5)
        t_cancel = time.monotonic()
        click(driver, driver.find_element(By.CSS_SELECTOR, '.action[data-action="fibonacci"] button.cancel'))
        cancel = wire.wait_for(lambda m: m.topic.endswith("/cancel/fibonacci"), timeout=3).json()
        assert cancel["id"] == long_id, cancel
        canceled = wait_until("canceled", lambda: (g := goal_panel(driver))["status"] == "canceled" and g, timeout=5)
        took = time.monotonic() - t_cancel
        terms = len(canceled["result"].split(","))
        assert 2 < terms < 41 and canceled["fraction"] < 1.0, canceled  # stopped before the end
        print(f"goal order 40 canceled: result after {took * 1000:.0f} ms with {terms} of 41 terms")

        # -- a goal the bridge refuses (motion blocked by the page's own emergency stop): the refusal comes on
        #    to/alice/error with the goal's id, and the panel says so
        try:
            driver.find_element(By.ID, "estop").click()
            wait_until("turtle1 stopped", lambda: (robot_row(driver, "turtle1") or {}).get("status") == "emergency")
            send_goal(driver, "5")
            refused = wait_until("the bridge's refusal", lambda: (g := goal_panel(driver))["status"] != "sending"
                                 and g, timeout=5)
            assert refused["status"] == "refused" and "send cmd/arm to resume" in refused["text"], refused
            assert "refused goal/fibonacci" in errors_text(driver), errors_text(driver)
            print(f"goal while e-stopped: {refused['text']!r}")
            click(driver, driver.find_element(By.ID, "arm"))
            wait_until("turtle1 active again", lambda: (robot_row(driver, "turtle1") or {}).get("status") == "active")
        except BaseException:
            arm_if_blocked(stack)
            raise

        # -- parameters: listed with values; a set from the panel reaches the ROS node
        row = wait_until("max_speed in the parameter panel", lambda: (r := param_row(driver, "max_speed"))
                         and r["value"] != "…" and r["type"] and r)
        assert row == {"value": "1", "type": "double", "edit": True, "set": True}, row
        assert (param_row(driver, "scan_beams") or {}).get("value") == "360"
        edit = driver.find_element(By.CSS_SELECTOR, '.params input[data-param="max_speed"]')
        set_button = driver.find_element(By.CSS_SELECTOR, '.params button.set[data-param="max_speed"]')
        try:
            wire.drain(0.2)
            edit.send_keys("fast")  # not a double: said on the page, nothing sent
            click(driver, set_button)
            assert param_result(driver)[0] == "invalid" and "not a number" in param_result(driver)[1]
            never("an invalid parameter set published", lambda: [
                (m.topic, m.payload) for m in wire.drain(0.01) if "/param/" in m.topic and b'"set"' in m.payload],
                seconds=0.5)
            edit.clear()
            edit.send_keys("0.35")
            t_set = time.monotonic()
            click(driver, set_button)
            wait_until("the set's answer", lambda: param_result(driver)[0] == "ok", timeout=10)
            assert ros_parameter(stack, "max_speed") == pytest.approx(0.35)
            wait_until("the new value in the panel", lambda: param_row(driver, "max_speed")["value"] == "0.35")
            print(f"parameter max_speed set to 0.35 from the page: ROS node reads it "
                  f"{(time.monotonic() - t_set) * 1000:.0f} ms after Set ({param_result(driver)[1]!r})")
            # the node's own validation (its range is 0..5) refuses, and the page shows its reason
            edit.send_keys("9")
            click(driver, set_button)
            result, text = wait_until("the node's refusal", lambda: (r := param_result(driver))[0] == "refused" and r,
                                      timeout=10)
            assert "max_speed not set:" in text and ros_parameter(stack, "max_speed") == pytest.approx(0.35), text
            print(f"parameter max_speed = 9 refused: {text!r}")
        finally:
            set_max_speed_over_mqtt(stack, 1.0)
        # someone else's change (the restore above) reaches the panel through state/parameter_events
        wait_until("the restored value in the panel", lambda: param_row(driver, "max_speed")["value"] == "1")
        no_console_errors(driver)
    print(f"panels test: {time.monotonic() - t_test:.1f} s")


def test_bob_reads_parameters_but_gets_no_set_button_and_no_goal_form(stack, tmp_path) -> None:
    from selenium.webdriver.common.by import By

    with browser(tmp_path, "bob-panels") as driver:
        login(driver, stack["url"], "bob", "bob-demo")
        logged_in(driver, "bob")
        wait_until("bob's role", lambda: (robot_row(driver, "turtle1") or {}).get("role") == "viewer")
        row = wait_until("max_speed's value", lambda: (r := param_row(driver, "max_speed")) and r["value"] != "…"
                         and r, timeout=15)
        assert row["value"] == "1" and not row["edit"] and not row["set"], row
        assert not driver.find_elements(By.CSS_SELECTOR, ".params button.set, .params input")
        assert driver.find_element(By.CSS_SELECTOR, '.params[data-params="sim_robot"]').get_attribute(
            "data-can-set") == "no"
        assert "read-only for you" in driver.find_element(By.ID, "params-box").text
        # fibonacci is operators-only: bob's access report lists no action, so no panel and no goal form
        assert not visible(driver, "actions-box")
        assert not driver.find_elements(By.CSS_SELECTOR, "form[data-action], .action button")
        assert driver.execute_script("return window.dashboard.robots.get('turtle1').access.actions") == []
        # the read-only service's form works for him
        form = driver.find_element(By.CSS_SELECTOR, '#services form[data-service="list_parameters"]')
        form.find_element(By.CSS_SELECTOR, 'input[data-field="depth"]').send_keys("1")
        click(driver, form.find_element(By.CSS_SELECTOR, "button.submit"))
        wait_until("bob's list_parameters reply", lambda: driver.execute_script(
            "return document.getElementById('service-result').dataset.result") == "ok")
        assert "max_speed" in driver.find_element(By.ID, "service-result").text
        no_console_errors(driver)
