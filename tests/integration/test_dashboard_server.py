"""The dashboard's static server and ``roslink-mqtt dashboard``: exactly the page's files, nothing else (no browser).

The server is part of the security model (docs/dashboard.md): it must never serve a file outside its fixed
list, hold or pass on credentials, or reveal fleet data; the browser tests cover what the page does.
"""

from __future__ import annotations

import http.client
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from roslink_mqtt.dashboard import DEFAULT_MQTT_JS, DashboardServer, MqttJsMissing
from roslink_mqtt.localproc import free_port
from tests.support.procs import CONFIG, ROOT
from tests.support.waits import wait_until

pytestmark = [
    pytest.mark.timeout(60),
    pytest.mark.skipif(not DEFAULT_MQTT_JS.is_file(), reason="MQTT.js not installed (make install)"),
]


def _get(port: int, path: str, method: str = "GET") -> tuple[int, dict[str, str], bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.putrequest(method, path, skip_accept_encoding=True)  # the raw path, '..' and all
        conn.endheaders()
        resp = conn.getresponse()
        return resp.status, {k.lower(): v for k, v in resp.getheaders()}, resp.read()
    finally:
        conn.close()


def test_serves_exactly_the_page_files() -> None:
    with DashboardServer("127.0.0.1", 0, ws_port=18083, prefix="fleet7") as server:
        assert server.url == f"http://127.0.0.1:{server.port}/"
        status, headers, body = _get(server.port, "/")
        assert status == 200 and headers["content-type"].startswith("text/html") and b"main.mjs" in body
        assert "script-src 'self'" in headers["content-security-policy"]
        assert "frame-ancestors 'none'" in headers["content-security-policy"]
        assert headers["x-frame-options"] == "DENY" and headers["cache-control"] == "no-store"
        assert "Python" not in headers["server"]
        status, headers, body = _get(server.port, "/vendor/mqtt.min.js")
        assert status == 200 and body == DEFAULT_MQTT_JS.read_bytes()  # MQTT.js from node_modules, as installed
        status, _, body = _get(server.port, "/config.json?x=1")
        assert status == 200 and json.loads(body) == {"ws_port": 18083, "ws_url": "", "prefix": "fleet7", "tiles": "",
                                                      "tiles_attribution": ""}
        for path in ("/main.mjs", "/views/fleet.mjs", "/style.css", "/vendor/uPlot.esm.js", "/vendor/uPlot.min.css"):
            status, headers, _ = _get(server.port, path)
            assert status == 200 and headers["content-type"].startswith(("text/javascript", "text/css")), path
        status, headers, body = _get(server.port, "/main.mjs", "HEAD")
        assert status == 200 and body == b"" and int(headers["content-length"]) > 1000
        for path in ("/server.py", "/../server.py", "/static/main.mjs", "/%2e%2e/server.py", "/vendor/mqtt.js",
                     "/vendor/../../pyproject.toml", "/config/robots.yaml", "//etc/passwd", "/index.html/",
                     "/views/", "/views/../server.py", "/vendor/uPlot.d.ts", "/app.js"):
            assert _get(server.port, path)[0] == 404, path
        assert _get(server.port, "/", "POST")[0] == 501  # no method but GET and HEAD


def test_a_page_of_another_origin_reaches_only_the_public_files() -> None:
    """What a foreign web page can get (issue 49's review): its requests reach the server (a page in another tab,
    or one whose DNS name rebinds to 127.0.0.1 and so sends a Host of its own), but no response lets another
    origin read it (no CORS header) and, read anyway through rebinding, every one is a file of the public page or
    config.json's four settings: no credentials, no fleet data, nothing that acts as anyone."""
    with DashboardServer("127.0.0.1", 0, ws_port=18083) as server:
        conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
        try:
            for path in ("/", "/config.json", "/main.mjs"):
                conn.request("GET", path, headers={"Origin": "http://evil.example", "Host": "evil.example:8090"})
                resp = conn.getresponse()
                body = resp.read()
                assert resp.status == 200, path
                assert not [h for h, _ in resp.getheaders() if h.lower().startswith("access-control-")], path
                if path == "/config.json":
                    assert set(json.loads(body)) == {"ws_port", "ws_url", "prefix", "tiles", "tiles_attribution"}
                assert b"-demo" not in body and b"password_hash" not in body, path
            conn.request("OPTIONS", "/config.json", headers={"Origin": "http://evil.example",
                                                             "Access-Control-Request-Method": "GET"})
            resp = conn.getresponse()
            resp.read()
            assert resp.status == 501 and resp.getheader("Access-Control-Allow-Origin") is None  # no preflight
        finally:
            conn.close()


def test_map_tiles_are_checked_and_allowed_from_their_origin_only() -> None:
    """--tiles: a URL template with {z}/{x}/{y}; the page's policy lets images come from that origin, nothing more."""
    with DashboardServer("127.0.0.1", 0, tiles="https://tiles.example.org/osm/{z}/{x}/{y}.png",
                         tiles_attribution="© OpenStreetMap contributors") as server:
        _, headers, body = _get(server.port, "/config.json")
        assert json.loads(body)["tiles"] == "https://tiles.example.org/osm/{z}/{x}/{y}.png"
        policy = headers["content-security-policy"]
        assert "img-src 'self' data: blob: https://tiles.example.org;" in policy
        assert "connect-src 'self' ws: wss:;" in policy  # tiles are images: no new place to send data to
    for bad, why in (("ftp://x/{z}/{x}/{y}", "expected http"), ("https://x/{z}/{x}.png", "{y} missing"),
                     ("https://x/{z}/{x}/{y}.png; script-src *", "not allowed"), ("/{z}/{x}/{y}", "expected http")):
        with pytest.raises(ValueError, match=re.escape(why)):
            DashboardServer("127.0.0.1", 0, tiles=bad)


def test_missing_mqtt_js_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(MqttJsMissing, match="run `make install`"):
        DashboardServer("127.0.0.1", 0, mqtt_js=tmp_path / "mqtt.min.js")


def _cli(*args: str, timeout: float = 20) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "dashboard", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout, stdin=subprocess.DEVNULL)


def test_cli_serves_the_fleet_ws_port_and_stops_on_ctrl_c(tmp_path: Path) -> None:
    fleet = tmp_path / "robots.yaml"
    fleet.write_text(CONFIG.read_text().replace("ws_port: 8083", "ws_port: 18093", 1))
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "roslink_mqtt.cli.main", "dashboard", "--config", str(fleet),
                             "--port", str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"}, start_new_session=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith(f"dashboard on http://127.0.0.1:{port}/") and "ws://<page host>:18093" in line, line
        status, _, body = _get(port, "/config.json")
        assert status == 200 and json.loads(body)["ws_port"] == 18093
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(10) == 0
        assert "Traceback" not in proc.stdout.read()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    def free() -> bool:
        try:
            _get(port, "/")
        except OSError:
            return True
        return False

    wait_until(f"port {port} no longer served after exit", free, timeout=5, period=0.1)


def test_cli_errors_say_why() -> None:
    no_ws = _cli("--ws-port", "0")
    assert no_ws.returncode == 2 and "no WebSocket listener" in no_ws.stderr
    no_js = _cli("--port", "0", "--mqtt-js", "/nonexistent/mqtt.min.js")
    assert no_js.returncode == 2 and "MQTT.js browser bundle not found" in no_js.stderr
    with DashboardServer("127.0.0.1", 0) as busy:
        taken = _cli("--port", str(busy.port))
    assert taken.returncode == 2 and f"cannot serve on 127.0.0.1:{busy.port}" in taken.stderr
    assert "Traceback" not in no_ws.stderr + no_js.stderr + taken.stderr
