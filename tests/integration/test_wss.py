"""``wss://`` (MQTT over WebSocket over TLS) on Mosquitto's own listener, configured as docs/clients.md shows it.

The Mosquitto block of the docs' "WebSocket over TLS" section is read from docs/clients.md (only its port, address
and certificate paths are substituted) and appended to the ``mosquitto.conf`` that ``roslink-mqtt acl export``
writes for a copy of the demo fleet; a throw-away CA signs a server certificate for 127.0.0.1/localhost (openssl
CLI). turtle1 (sim + bridge) runs against that Mosquitto on its plain listener. Then, with MQTT.js from
node_modules:

* alice, trusting the CA, reads turtle1's retained heartbeat and her retained access report through the TLS
  listener; bob's replies and a wrong password are refused there (the fleet's ACL and logins cover the added
  listener);
* the unchanged starter examples/mqttjs/watch_and_drive.js drives turtle1 over ``wss://`` (the CA given to Node
  with NODE_EXTRA_CA_CERTS): the twists reach ROS ``/cmd_vel`` and the robot moves on ``/odom``;
* TLS is enforced: a client that does not trust the CA (Node's default store, or another CA) fails with a
  certificate error, and plain ``ws://`` on the TLS port never gets an MQTT session;
* the listener binds 127.0.0.1 only (with the documented ``socket_domain`` line).
"""

from __future__ import annotations

import json
import math
import os
import pwd
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import pytest

from roslink_mqtt.localproc import Mosquitto, free_port, mosquitto_exe, replace_once, wait_for_port
from tests.support.broker_setup import ExportedMosquitto, write_fleet
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT, bridge_args, bridge_env, run
from tests.support.ros import RosProbe

pytestmark = [pytest.mark.timeout(120),
              pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")]

DOCS = ROOT / "docs" / "clients.md"
NODE = shutil.which("node")
STARTER = ROOT / "examples" / "mqttjs" / "watch_and_drive.js"
MOSQUITTO = mosquitto_exe() or "/usr/sbin/mosquitto"
CERT_ERRORS = {"UNABLE_TO_VERIFY_LEAF_SIGNATURE", "SELF_SIGNED_CERT_IN_CHAIN", "DEPTH_ZERO_SELF_SIGNED_CERT",
               "UNABLE_TO_GET_ISSUER_CERT_LOCALLY", "UNABLE_TO_GET_ISSUER_CERT", "CERT_SIGNATURE_FAILURE"}


# -- the docs' block -------------------------------------------------------------------------------------------------
def docs_mosquitto_block() -> str:
    """The fenced block after "**Mosquitto's own TLS**" in the wss section of docs/clients.md."""
    text = DOCS.read_text()
    section = text.split("## WebSocket over TLS (`wss://`)", 1)[1].split("\n## ", 1)[0]
    after = section.split("**Mosquitto's own TLS**", 1)[1]
    match = re.search(r"^```[^\n]*\n(.*?)^```", after, re.M | re.S)
    assert match, "docs/clients.md: no fenced block after \"Mosquitto's own TLS\""
    return match.group(1)


def wss_listener_conf(port: int, certs: Path) -> str:
    """The docs' block with this test's port, loopback address and certificate directory.

    ``listener 8884`` becomes ``listener PORT 127.0.0.1`` plus ``socket_domain ipv4``: the docs' way to bind one
    address (Mosquitto 2.0.11 binds a WebSocket port on every interface without it). Every substitution must find
    its text exactly once, so a changed docs block fails here instead of testing something else.
    """
    conf = docs_mosquitto_block()
    conf = replace_once(conf, "listener 8884\n", f"listener {port} 127.0.0.1\nsocket_domain ipv4\n")
    conf = replace_once(conf, "certfile /etc/mosquitto/certs/fullchain.pem\n", f"certfile {certs}/fullchain.pem\n")
    conf = replace_once(conf, "keyfile /etc/mosquitto/certs/privkey.pem\n", f"keyfile {certs}/privkey.pem\n")
    return conf


def test_docs_block_is_a_websocket_tls_listener() -> None:
    lines = [line.split()[0] for line in docs_mosquitto_block().splitlines() if line.strip()]
    assert lines == ["listener", "protocol", "certfile", "keyfile"], lines
    assert "protocol websockets\n" in docs_mosquitto_block()


# -- a throw-away CA -------------------------------------------------------------------------------------------------
def _openssl(*args: str) -> None:
    done = subprocess.run(["openssl", *args], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr


def make_ca(directory: Path, name: str) -> tuple[Path, Path]:
    """A self-signed CA (EC P-256, valid 2 days): (certificate, key)."""
    directory.mkdir(parents=True, exist_ok=True)
    cert, key = directory / f"{name}.pem", directory / f"{name}.key"
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes", "-days", "2",
             "-subj", f"/CN={name}", "-addext", "basicConstraints=critical,CA:TRUE",
             "-addext", "keyUsage=critical,keyCertSign,cRLSign", "-keyout", str(key), "-out", str(cert))
    return cert, key


def make_server_cert(directory: Path, ca: tuple[Path, Path]) -> None:
    """``fullchain.pem`` / ``privkey.pem`` in ``directory``: a server certificate for 127.0.0.1 and localhost."""
    csr, ext = directory / "server.csr", directory / "server.ext"
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes", "-subj", "/CN=localhost",
             "-keyout", str(directory / "privkey.pem"), "-out", str(csr))
    ext.write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n"
                   "basicConstraints=critical,CA:FALSE\n")
    _openssl("x509", "-req", "-in", str(csr), "-CA", str(ca[0]), "-CAkey", str(ca[1]), "-set_serial",
             str(int.from_bytes(os.urandom(8), "big")), "-days", "2", "-extfile", str(ext),
             "-out", str(directory / "fullchain.pem"))


# -- MQTT.js ---------------------------------------------------------------------------------------------------------
# One connection: prints one JSON line per event; exits 0 once the robot's heartbeat and the user's access report
# arrived, 1 on an error or a close, 2 after 10 s. The CA (if any) is given as MQTT.js's `ca` option.
PROBE = r"""
const fs = require('fs');
const mqtt = require('mqtt');
const env = process.env;
const say = (event, extra) => console.log(JSON.stringify({ event, ...extra }));
const opts = { username: env.PROBE_USER, password: env.PROBE_PASSWORD, connectTimeout: 5000, reconnectPeriod: 0,
  clientId: `${env.PROBE_USER}-wss-test-${process.pid}` };
if (env.PROBE_CA) opts.ca = fs.readFileSync(env.PROBE_CA);
const base = `roslink/${env.PROBE_ROBOT}`;
const want = new Set([`${base}/heartbeat`, `${base}/to/${env.PROBE_USER}/access`]);
const client = mqtt.connect(env.PROBE_URL, opts);
let done = false;
setTimeout(() => { say('timeout'); process.exit(2); }, 10000);
client.on('connect', () => {
  say('connected');
  // First bob's topics, which alice may not read: Mosquitto grants the filter, its ACL must drop his retained access
  // report (sent before the retained messages of the later filters, so it would be seen before the probe ends).
  client.subscribe([`${base}/to/bob/#`, ...want], { qos: 1 }, (err, granted) => say('subscribed',
    { err: err && err.message, granted: granted && granted.map((g) => g.qos) }));
});
client.on('message', (topic, payload, packet) => {
  say('message', { topic, retain: packet.retain, payload: payload.toString('utf8') });
  want.delete(topic);
  if (want.size === 0 && !done) { // linger 0.3 s for anything that should not come
    done = true;
    setTimeout(() => client.end(false, () => process.exit(0)), 300);
  }
});
client.on('error', (e) => { // a reset while closing after the job is done is no failure
  if (done) return;
  say('error', { code: e.code || null, message: e.message }); process.exit(1);
});
client.on('close', () => { if (!done) { say('closed'); process.exit(1); } });
"""


def probe(url: str, *, ca: Path | None = None, user: str = "alice", password: str = "alice-demo",
          env: dict[str, str] | None = None) -> tuple[int, list[dict], float]:
    """Run :data:`PROBE`: (exit code, its events, seconds taken)."""
    full_env = {k: v for k, v in os.environ.items() if k != "NODE_EXTRA_CA_CERTS"}
    full_env.update({"PROBE_URL": url, "PROBE_USER": user, "PROBE_PASSWORD": password, "PROBE_ROBOT": "turtle1",
                     **({"PROBE_CA": str(ca)} if ca else {}), **(env or {})})
    t0 = time.monotonic()
    done = subprocess.run([NODE, "-e", PROBE], env=full_env, cwd=ROOT, capture_output=True, text=True, timeout=30,
                          stdin=subprocess.DEVNULL)
    took = time.monotonic() - t0
    events = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    print(f"probe {url} ca={ca.name if ca else None} user={user}: exit {done.returncode} in {took:.2f} s: "
          f"{[e['event'] + (':' + str(e.get('code')) if e['event'] == 'error' else '') for e in events]}")
    assert not done.stderr.strip() or done.returncode != 0, done.stderr
    return done.returncode, events, took


# -- the stack -------------------------------------------------------------------------------------------------------
def _listening_addresses(port: int) -> set[str]:
    """Local addresses of the sockets listening on TCP ``port`` (from /proc/net/tcp and tcp6)."""
    found = set()
    for name, width in (("tcp", 8), ("tcp6", 32)):
        for line in Path(f"/proc/net/{name}").read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, hexport = local.split(":")
            if state == "0A" and int(hexport, 16) == port:
                assert len(address) == width
                found.add(address)
    return found


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    assert NODE, "node is not installed (.ci/run installs nodejs)"
    assert (ROOT / "node_modules" / "mqtt").is_dir(), "MQTT.js missing: run `make install` (npm ci)"
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry

    work = tmp_path_factory.mktemp("wss")
    certs = work / "certs"
    ca = make_ca(work / "ca", "roslink-test-ca")
    certs.mkdir()
    make_server_cert(certs, ca)
    other_ca, _ = make_ca(work / "other-ca", "some-other-ca")

    wss_port = free_port()
    conf = wss_listener_conf(wss_port, certs)
    fleet = write_fleet(work, read_only_service=False)
    t0 = time.monotonic()
    with ExportedMosquitto(work, fleet, extra_conf=conf) as broker, \
            run(["-m", "roslink_mqtt.sim"], work / "sim.log"), \
            run(bridge_args("turtle1", broker.port, config=fleet), work / "bridge.log", bridge_env("turtle1")):
        wait_for_port(wss_port, 10, proc=broker, what="mosquitto (wss listener)")
        with TestClient(broker.port, "bob", "bob-demo") as bob:
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/heartbeat")
            bob.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=20)
        print(f"Mosquitto (exported conf + the docs' wss block) and turtle1 up in {time.monotonic() - t0:.1f} s")
        probe_ros = RosProbe()
        try:
            yield {"broker": broker, "conf": conf, "wss_port": wss_port, "ca": ca[0], "other_ca": other_ca,
                   "cmd_vel": probe_ros.watch(Twist, "/cmd_vel"), "odom": probe_ros.watch(Odometry, "/odom")}
        finally:
            probe_ros.close()


def test_broker_runs_the_docs_block_bound_to_loopback(stack) -> None:
    assert stack["conf"] in stack["broker"].conf.read_text()
    assert _listening_addresses(stack["wss_port"]) == {"0100007F"}, "the wss listener must bind 127.0.0.1 only"
    assert "Opening websockets listen socket on port" in stack["broker"].output()


def test_mqttjs_reads_retained_state_over_wss(stack) -> None:
    url = f"wss://127.0.0.1:{stack['wss_port']}"
    code, events, _ = probe(url, ca=stack["ca"])
    assert code == 0, events
    assert events[0]["event"] == "connected"
    subscribed = next(e for e in events if e["event"] == "subscribed")
    assert subscribed["err"] is None and subscribed["granted"] == [1, 1, 1], subscribed
    messages: dict[str, dict] = {}  # the first of each topic: the retained one (live heartbeats follow)
    for e in events:
        if e["event"] == "message":
            messages.setdefault(e["topic"], e)
    assert set(messages) == {"roslink/turtle1/heartbeat", "roslink/turtle1/to/alice/access"}, messages
    heartbeat = messages["roslink/turtle1/heartbeat"]
    assert heartbeat["retain"] is True
    assert json.loads(heartbeat["payload"])["payload"]["system_status"] == 4
    access = messages["roslink/turtle1/to/alice/access"]
    assert access["retain"] is True and json.loads(access["payload"])["role"] == "operator", access

    # The ACL held (above: bob's access report, retained, never reached alice; bob reads it on the plain listener),
    # and so do the fleet's logins (per_listener_settings false in the export).
    with TestClient(stack["broker"].port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe("roslink/turtle1/to/bob/access")
        assert bob.wait_for(lambda m: True, timeout=5).json()["role"] == "viewer"
    code, events, _ = probe(url, ca=stack["ca"], password="not-her-password")
    assert code == 1 and not any(e["event"] == "connected" for e in events), events
    assert [e["code"] for e in events if e["event"] == "error"] == [5], events  # CONNACK: not authorized


def test_starter_drives_turtle1_over_wss(stack) -> None:
    cmd_vel, odom = stack["cmd_vel"], stack["odom"]
    odom.wait_for(lambda m: True, timeout=10)
    t0 = time.monotonic()
    start = [m for t, m in odom.since(0) if t <= t0][-1].pose.pose.position
    env = {**os.environ, "ROSLINK_URL": f"wss://127.0.0.1:{stack['wss_port']}", "ROSLINK_USERNAME": "alice",
           "ROSLINK_PASSWORD": "alice-demo", "NODE_EXTRA_CA_CERTS": str(stack["ca"])}
    out = subprocess.run([NODE, str(STARTER), "--robot", "turtle1", "--seconds", "1.5", "--speed", "0.3"], env=env,
                         cwd=ROOT, capture_output=True, text=True, timeout=30, stdin=subprocess.DEVNULL)
    print(out.stdout, out.stderr)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"connected to wss://127.0.0.1:{stack['wss_port']} as alice" in out.stdout
    assert re.search(r"^heartbeat turtle1: active \(status 4\)", out.stdout, re.M), out.stdout

    forward = [t for t, m in cmd_vel.since(t0) if m.linear.x == pytest.approx(0.3) and m.angular.z == 0]
    assert len(forward) >= 10, f"{len(forward)} forward twists reached /cmd_vel"
    stopped_at, _ = cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, after=forward[-1], timeout=3)
    # the sim obeyed the stop: its odometry says so, and the pose stays where it is from then on
    odom.wait_for(lambda m: m.twist.twist.linear.x == 0 and m.twist.twist.angular.z == 0, after=stopped_at,
                  timeout=10)
    end = [m for _, m in odom.since(0)][-1].pose.pose.position
    moved = math.dist((start.x, start.y), (end.x, end.y))
    print(f"MQTT.js starter over wss://: {len(forward)} twists on /cmd_vel, turtle1 moved {moved:.2f} m on /odom")
    assert 0.2 < moved < 0.8, moved


def test_tls_is_enforced(stack) -> None:
    port = stack["wss_port"]
    # Not trusting the CA: Node's default store, and another CA given as `ca`.
    for ca in (None, stack["other_ca"]):
        code, events, took = probe(f"wss://127.0.0.1:{port}", ca=ca)
        assert code == 1, events
        errors = [e for e in events if e["event"] == "error"]
        assert errors and errors[0]["code"] in CERT_ERRORS, events
        assert not any(e["event"] == "connected" for e in events)
        assert took < 10
    # The right CA through NODE_EXTRA_CA_CERTS instead of `ca` connects (what the drive test relies on).
    code, events, _ = probe(f"wss://127.0.0.1:{port}", env={"NODE_EXTRA_CA_CERTS": str(stack["ca"])})
    assert code == 0, events
    # Plain WebSocket on the TLS port: no MQTT session, an error or a close (not a timeout).
    code, events, took = probe(f"ws://127.0.0.1:{port}", ca=stack["ca"])
    assert code == 1 and not any(e["event"] == "connected" for e in events), events
    assert took < 10


# -- the key must be readable by the user Mosquitto drops to ---------------------------------------------------------
def _mosquitto_account() -> pwd.struct_passwd | None:
    try:
        return pwd.getpwnam("mosquitto")
    except KeyError:
        return None


@pytest.mark.skipif(os.geteuid() != 0 or _mosquitto_account() is None,
                    reason="needs root and the user 'mosquitto' (Mosquitto drops to it only when started as root)")
def test_a_key_only_root_can_read_stops_the_listener() -> None:
    account = _mosquitto_account()
    assert account is not None
    # Not pytest's tmp_path: its directories are 0700, which the user 'mosquitto' cannot even enter.
    base = Path(tempfile.mkdtemp(prefix="roslink-wss-", dir="/tmp"))
    try:
        base.chmod(0o755)
        certs = base / "certs"
        certs.mkdir(mode=0o755)
        make_server_cert(certs, make_ca(base / "ca", "roslink-test-ca"))
        key = certs / "privkey.pem"
        (certs / "fullchain.pem").chmod(0o644)
        key.chmod(0o600)  # root's only, as Let's Encrypt's privkey.pem
        wss_port, plain_port = free_port(), free_port()
        conf = (f"user mosquitto\nlistener {plain_port} 127.0.0.1\nallow_anonymous false\npersistence false\n"
                f"log_dest stderr\n{wss_listener_conf(wss_port, certs)}")
        (base / "refused.conf").write_text(conf)
        done = subprocess.run([MOSQUITTO, "-c", str(base / "refused.conf")], capture_output=True, text=True,
                              timeout=10, stdin=subprocess.DEVNULL)
        print(done.stderr)
        assert done.returncode != 0
        assert f"Error: Unable to create websockets listener on port {wss_port}." in done.stderr

        os.chown(key, 0, account.pw_gid)
        key.chmod(0o640)  # what the docs say to do
        with Mosquitto(base, conf, plain_port) as broker:
            wait_for_port(wss_port, 10, proc=broker, what="mosquitto (wss listener)")
            assert _listening_addresses(wss_port) == {"0100007F"}
    finally:
        shutil.rmtree(base, ignore_errors=True)
