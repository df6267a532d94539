"""The dashboard as an operations console, in real headless Chromium: ten simulated robots (tests/support/sim_fleet.py,
MQTT only) on the embedded broker, seen by ``ops`` (operator of all of them).

The fleet overview (map, attention list, alerts), the alert rules and their acknowledgements, the GPS map on map
tiles from a local tile server, a robot's time series, and a soak: the page's heap, DOM and CPU stay level while ten
robots stream. ``DASHBOARD_SCREENSHOT_DIR=dir`` saves the console at both widths there (docs/dashboard.md's
figures come from such a run).
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from roslink_mqtt.dashboard import DashboardServer
from tests.support.browser import (
    CHROMIUM,
    browser,
    click_css,
    logged_in,
    login,
    no_console_errors,
    robot_row,
    visible,
    wait_until,
)
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.page_soak import cpu_share, soak, table
from tests.support.sim_fleet import PASSWORD, SimulatedFleet, robot_name, write_sim_fleet

pytestmark = [pytest.mark.timeout(240), CHROMIUM]
ROBOTS = 10
SOAK_SECONDS = 30.0  # bench/dashboard_soak.py runs ten minutes
# a 1×1 PNG: what the local tile server answers for every tile
PNG = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000"
                    "1f15c4890000000d49444154789c6360f8cfc0f01f0005000201a2e0b0a80000000049454e44ae426082")


class TileServer:
    """A map tile server on 127.0.0.1 that answers every ``/{z}/{x}/{y}.png`` with a PNG and notes the path."""

    def __init__(self) -> None:
        requests = self.requests = []

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802
                requests.append(self.path)
                self.send_response(200)
                self.send_header("Content-Type", "image/png")
                self.send_header("Content-Length", str(len(PNG)))
                self.end_headers()
                self.wfile.write(PNG)

            def log_message(self, *args: object) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True).start()
        self.template = f"http://127.0.0.1:{self.httpd.server_address[1]}/{{z}}/{{x}}/{{y}}.png"

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Iterator[dict[str, Any]]:
    """Broker (TCP + WebSocket) with a ten-robot fleet file, the simulated robots, a tile server, the page's server."""
    work = tmp_path_factory.mktemp("fleet")
    config = write_sim_fleet(work / "fleet.yaml", ROBOTS, port=1883, ws_port=8083)  # the broker takes free ports
    tiles = TileServer()
    with EmbeddedBrokerProcess(work, config, ws=True) as broker:
        sim = SimulatedFleet(broker.port, ROBOTS)
        sim.robots["sim08"].battery = 6    # critical: under half the 20 % line
        sim.robots["sim09"].battery = 15   # warning
        sim.robots["sim04"].link_quality = 0.3
        sim.start(seconds=600)
        server = DashboardServer("127.0.0.1", 0, ws_port=broker.ws_port, tiles=tiles.template,
                                 tiles_attribution="test tiles").start()
        try:
            yield {"broker": broker, "sim": sim, "url": server.url, "tiles": tiles}
        finally:
            server.stop()
            sim.stop()
            tiles.stop()


def ops_ready(driver: Any, fleet: dict[str, Any]) -> None:
    login(driver, fleet["url"], "ops", PASSWORD)
    logged_in(driver, "ops")
    for i in range(ROBOTS):
        wait_until(f"{robot_name(i)} online", lambda i=i: (robot_row(driver, robot_name(i)) or {}).get("presence")
                   in ("online", "stale"))


def attention(driver: Any) -> list[tuple[str, str, str]]:
    """The attention list as shown: (robot, level, why), most urgent first."""
    return [tuple(x) for x in driver.execute_script(
        "return [...document.querySelectorAll('#attention li')].map(li => "
        "[li.dataset.robot, li.dataset.level, li.querySelector('.why').textContent])")]


def alerts(driver: Any) -> list[dict[str, str]]:
    return driver.execute_script(
        "return [...document.querySelectorAll('#alerts li')].map(li => ({key: li.dataset.key, "
        "robot: li.dataset.robot, kind: li.dataset.kind, severity: li.dataset.severity, state: li.dataset.state, "
        "text: li.textContent}))")


def shot(driver: Any, name: str) -> None:
    if os.environ.get("DASHBOARD_SCREENSHOT_DIR"):
        driver.save_screenshot(str(Path(os.environ["DASHBOARD_SCREENSHOT_DIR"]) / f"{name}.png"))


@pytest.mark.parametrize("width", [1280, 400])
def test_the_fleet_at_a_glance_with_alerts_map_and_charts(fleet, tmp_path, width: int) -> None:
    """ops sees ten robots: on the map, in the attention list by urgency (battery, link; then a robot whose link
    goes down), in alerts she acknowledges (kept acknowledged after a reload), on GPS map tiles; a click opens a
    robot, whose charts fill; at 400 px nothing scrolls sideways and the e-stop stays in the window."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    sim = fleet["sim"]
    silent = "sim05" if width == 1280 else "sim06"  # each run its own outage (the other's is over)
    with browser(tmp_path, f"fleet-{width}") as driver:
        driver.set_window_size(width, 800)
        ops_ready(driver, fleet)
        driver.find_element(By.ID, "tab-fleet").click()
        assert visible(driver, "fleet-view") and not visible(driver, "robot-view")
        names = wait_until("every robot on the map", lambda: len((m := driver.find_element(
            By.ID, "fleet-map").get_attribute("data-robots") or "").split()) == ROBOTS and m)
        assert sorted(names.split()) == [robot_name(i) for i in range(ROBOTS)]

        # urgency: the critical battery, the low one, the thin link; the rest are ok
        top = wait_until("the attention list by urgency", lambda: (a := attention(driver)) and [
            r for r, _, _ in a[:3]] == ["sim08", "sim09", "sim04"] and a[:3])
        assert [lvl for _, lvl, _ in top] == ["critical", "warning", "note"], top
        assert top[0][2] == "battery 6 %" and "uplink carries 30 %" in top[2][2], top
        assert all(lvl == "ok" for _, lvl, _ in attention(driver)[3:])
        battery = wait_until("battery alerts", lambda: (a := [x for x in alerts(driver) if x["kind"] == "battery"])
                             and len(a) == 2 and a)
        assert {(a["robot"], a["severity"]) for a in battery} == {("sim08", "critical"), ("sim09", "warning")}

        # a robot's link goes down: stale at the top of the list and a critical alert, within the stale time
        # every listed robot keeps its item while the list changes around it (a rebuilt item swallows a click)
        driver.execute_script("window.kept = document.querySelector('#attention li[data-robot=\"sim08\"] button')")
        sim.silence(silent)
        try:
            wait_until(f"{silent} first in the list", lambda: attention(driver)[0][:2] == (silent, "critical"),
                       timeout=15)
            assert driver.execute_script("return window.kept.isConnected && window.kept === document.querySelector("
                                         "'#attention li[data-robot=\"sim08\"] button')")
            alert = wait_until("the stale alert", lambda: next((a for a in alerts(driver) if a["robot"] == silent
                                                                and a["kind"] == "stale"), None))
            assert alert["severity"] == "critical" and alert["state"] == "active" and "no heartbeat" in alert["text"]
            assert driver.find_element(By.ID, "fleet-badge").text == "3"
            shot(driver, f"dashboard-fleet-{width}")
            click_css(driver, f'#alerts li[data-key="{alert["key"]}"] button.ack')
            wait_until("acknowledged", lambda: driver.find_element(By.ID, "fleet-badge").text == "2")

            # acknowledged stays acknowledged for the session: a reload (and a new login) keeps it so
            driver.refresh()
            ops_ready(driver, fleet)
            driver.find_element(By.ID, "tab-fleet").click()
            again = wait_until("the stale alert after the reload", lambda: next(
                (a for a in alerts(driver) if a["key"] == alert["key"]), None), timeout=15)
            assert again["state"] == "acknowledged", again
            wait_until("only the battery alerts wait", lambda: driver.find_element(By.ID, "fleet-badge").text == "2")
        finally:
            sim.resume(silent)

        # a failsafe stop is an alert of its own
        sim.failsafe("sim02", "operator ops went away (last-will)")
        failsafe = wait_until("the failsafe alert", lambda: next((a for a in alerts(driver)
                                                                  if a["kind"] == "failsafe"), None))
        assert failsafe["robot"] == "sim02" and failsafe["severity"] == "critical"
        assert "operator ops went away" in failsafe["text"]

        # GPS: the three robots with a fix, on tiles from the configured server (allowed by the page's policy)
        Select(driver.find_element(By.ID, "map-mode")).select_by_value("gps")
        wait_until("GPS robots on the map", lambda: sorted((driver.find_element(By.ID, "fleet-map").get_attribute(
            "data-robots") or "").split()) == ["sim01", "sim02", "sim03"])
        wait_until("tiles fetched", lambda: len(fleet["tiles"].requests) >= 1)
        assert all(p.endswith(".png") and p.count("/") == 3 for p in fleet["tiles"].requests)
        assert "test tiles" in driver.find_element(By.ID, "map-note").text

        if width <= 640:  # a phone: the fleet view reflows, the stop buttons stay in reach
            inner = driver.execute_script("return [window.innerWidth, window.innerHeight]")
            assert driver.execute_script("return document.documentElement.scrollWidth") <= inner[0] + 1
            estop = driver.execute_script("const r = document.getElementById('estop').getBoundingClientRect(); "
                                          "return [r.top, r.bottom, r.height]")
            assert 0 <= estop[0] and estop[1] <= inner[1] and estop[2] >= 44, estop

        # a click in the attention list opens that robot; its charts fill as its series grow
        # the list is rebuilt while sim02's failsafe and sim06's return reach it: found afresh at the click
        click_css(driver, '#attention li[data-robot="sim08"] button')
        wait_until("the robot's view opened by the click", lambda: visible(driver, "robot-view"), timeout=5)
        assert not visible(driver, "fleet-view")
        assert driver.find_element(By.ID, "robot-title").text == "Robot sim08"
        points = wait_until("the charts filled", lambda: (p := driver.execute_script(
            "return Object.fromEntries([...document.querySelectorAll('.chart')].map(c => "
            "[c.dataset.series, +c.dataset.points]))")) and all(v >= 3 for v in p.values()) and p, timeout=15)
        assert set(points) == {"battery", "speed", "link"}
        assert driver.find_element(By.CSS_SELECTOR, '.chart[data-series="battery"] .latest').text == "6 %"
        assert len(driver.find_elements(By.CSS_SELECTOR, "#charts canvas")) == 3  # drawn by uPlot
        shot(driver, f"dashboard-robot-{width}")
        keyboard_and_names(driver)
        no_console_errors(driver)


def keyboard_and_names(driver: Any) -> None:
    """Screen-reader and keyboard basics: every visible control has a name (its text, label, aria-label or title),
    and Tab goes from Log out through the view tabs to STOP ALL and the e-stop, then into the view."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    unnamed = driver.execute_script("""
        const out = [];
        for (const e of document.querySelectorAll('button, input, select, textarea, [tabindex], canvas')) {
          if (!e.getClientRects().length) continue;  // not shown
          const label = e.labels && e.labels.length ? e.labels[0].textContent : '';
          const name = (e.getAttribute('aria-label') || label || e.textContent || e.title || '').trim();
          if (!name && !(e.closest('.uplot'))) out.push(e.outerHTML.slice(0, 100));
        }
        return out;""")
    assert unnamed == [], unnamed
    assert driver.execute_script("return document.querySelectorAll('[tabindex]:not([tabindex=\"0\"]):not("
                                 "[tabindex=\"-1\"])').length") == 0  # no order of its own: reading order
    driver.execute_script("window.scrollTo(0, 0); document.getElementById('logout').focus()")
    order = ["logout"]
    for _ in range(4):
        ActionChains(driver).send_keys(Keys.TAB).perform()
        order.append(driver.execute_script("return document.activeElement.id"))
    assert order == ["logout", "tab-fleet", "tab-robot", "stop-all", "estop"], order
    ActionChains(driver).send_keys(Keys.TAB).perform()  # then into the robot view
    assert driver.execute_script("return document.getElementById('robot-view').contains(document.activeElement)")


def test_ten_robots_streaming_keep_the_page_level(fleet, tmp_path) -> None:
    """Ten robots at 10 Hz each for SOAK_SECONDS, the fleet view shown (its map redrawn): after the first 10 s the
    heap grows by less than 5 MB and the DOM stays level; the page's CPU is printed (bench/dashboard_soak.py runs
    the same for ten minutes)."""
    from selenium.webdriver.common.by import By

    with browser(tmp_path, "soak", precise_memory=True) as driver:
        driver.set_window_size(1280, 800)
        ops_ready(driver, fleet)
        driver.find_element(By.ID, "tab-fleet").click()
        samples = soak(driver, SOAK_SECONDS, every=5.0)
        print("\n" + table(samples))
        warm = next(s for s in samples if s.t >= 10)
        last = samples[-1]
        print(f"page CPU over the soak: {cpu_share(warm, last) * 100:.1f} % of one core")
        assert last.heap_mb - warm.heap_mb < 5.0, f"heap grew from {warm.heap_mb:.2f} to {last.heap_mb:.2f} MB"
        assert last.elements <= warm.elements + 50, f"DOM grew from {warm.elements} to {last.elements} elements"
        assert last.nodes <= warm.nodes + 500, f"DOM nodes grew from {warm.nodes} to {last.nodes}"
        assert last.listeners <= warm.listeners + 100, f"listeners grew from {warm.listeners} to {last.listeners}"
        received = driver.execute_script("return [...window.dashboard.robots.values()].map(r => r.poses)")
        assert len(received) == ROBOTS and min(received) >= 8 * SOAK_SECONDS, received  # all ten kept coming
        trails = driver.execute_script("return [...window.dashboard.robots.values()].map(r => r.trail.length)")
        assert min(trails) >= 5 * SOAK_SECONDS, trails  # every robot's trail is kept, not only the shown one's
        no_console_errors(driver)
