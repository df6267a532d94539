"""A web page of another origin tries alice's Foxglove gateway in real headless Chromium, and gets nothing (issue 49).

The stack: the embedded broker and alice's ``roslink-mqtt foxglove`` (a real process, as she starts it). The attacker
is a page served by a little ``http.server`` of its own on another local port, as any site the operator visits
could be: it opens ``new WebSocket(...)`` to the gateway without a token, with a guessed one, even with the right
one, and to the SDK's own port behind the front (``ws://`` and ``wss://``), and records every event. None may open
or bring a message. As a control, the same browser opens tools/foxglove-view.html from disk (``Origin: null``, as
desktop Foxglove and Lichtblick) with the URL the gateway printed, and gets the server's info: the browser *can*
connect where it is allowed, so the refusals above are the gateway's.
"""

from __future__ import annotations

import functools
import http.server
import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from roslink_mqtt.localproc import LocalProcess
from tests.support.browser import CHROMIUM, browser, wait_until
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.foxglove_gateway import printed_url, start_gateway, upstream_port
from tests.support.procs import ROOT

pytestmark = [pytest.mark.timeout(120), CHROMIUM]

# Opens every URL in the page's query (JSON) and records what each WebSocket saw; `window.done` when all closed.
ATTACK_PAGE = """<!doctype html><meta charset="utf-8"><title>a page of another origin</title>
<script>
"use strict";
const targets = JSON.parse(decodeURIComponent(location.hash.slice(1)));
window.attempts = targets.map((url) => ({url, events: [], messages: 0}));
for (const attempt of window.attempts) {
  try {
    const ws = new WebSocket(attempt.url, ["foxglove.sdk.v1", "foxglove.websocket.v1"]);
    ws.onopen = () => attempt.events.push("open");
    ws.onmessage = () => { attempt.messages += 1; attempt.events.push("message"); };
    ws.onerror = () => attempt.events.push("error");
    ws.onclose = (e) => attempt.events.push(`close ${e.code}`);
  } catch (err) {
    attempt.events.push(`throw ${err}`, "close");
  }
}
window.done = () => window.attempts.every((a) => a.events.some((e) => e.startsWith("close")));
</script>
"""


@pytest.fixture(scope="module")
def gateway(tmp_path_factory) -> Iterator[LocalProcess]:
    """alice's gateway (every robot she sees: none here; the handshake is what is tried) on a real broker."""
    work = tmp_path_factory.mktemp("foxglove-origin")
    with EmbeddedBrokerProcess(work) as broker:
        proc = start_gateway(work, broker.port, "alice", robots=())
        try:
            yield proc
        finally:
            proc.stop()


@pytest.fixture()
def attacker_site(tmp_path) -> Iterator[str]:
    """http://127.0.0.1:<its own port>/ serving ATTACK_PAGE: another local origin, as a site in another tab."""
    (tmp_path / "attack.html").write_text(ATTACK_PAGE)
    handler = functools.partial(_QuietHandler, directory=str(tmp_path))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's signature)
        pass


def test_a_page_of_another_local_origin_gets_nothing(tmp_path: Path, gateway: LocalProcess,
                                                      attacker_site: str) -> None:
    url = printed_url(gateway)
    base, token = url.split("?token=")
    upstream = upstream_port(gateway)
    targets = [base, f"{base}?token=guess", f"{base}?token={token[:-2]}xx",
               url,  # even with the right token (stolen, or guessed): the origin is not allowed
               url.replace("127.0.0.1", "localhost"),
               f"ws://127.0.0.1:{upstream}/", f"wss://127.0.0.1:{upstream}/"]  # the SDK's own port, found by a scan
    with browser(tmp_path, "foxglove-origin") as driver:
        driver.get(f"{attacker_site}/attack.html#{json.dumps(targets)}")
        wait_until("every attempt closed", lambda: driver.execute_script("return window.done && window.done()"),
                   timeout=30)
        attempts = driver.execute_script("return window.attempts")
        for attempt in attempts:
            assert "open" not in attempt["events"] and attempt["messages"] == 0, attempt
            assert "error" in attempt["events"], attempt
        assert len(attempts) == len(targets)

        # the refusals are the gateway's, logged with the page's origin (not the browser's own doing)
        log = wait_until("the refusal in the gateway's output", lambda: (text := gateway.log.read_text()) and
                         f"origin {attacker_site}" in text and text)
        assert f"origin {attacker_site}: origin not allowed" in log
        assert "secure handshake failed" in log  # the SDK's port dropped the page's ws:// and wss:// attempts

        # the control: a page opened from disk, with the printed URL, does get the server's info
        driver.get(f"file://{ROOT / 'tools' / 'foxglove-view.html'}?url={url}")
        server = wait_until("the server info", lambda: driver.execute_script("return window.gatewayView.server"))
        assert server["name"] == "roslink-mqtt (alice)"
        driver.get(f"file://{ROOT / 'tools' / 'foxglove-view.html'}?url={base}")  # no token: refused, and said so
        said = wait_until("the page's message", lambda: driver.execute_script(
            "const t = document.getElementById('server').textContent; return t.startsWith('could not') && t"))
        assert "?token=" in said
