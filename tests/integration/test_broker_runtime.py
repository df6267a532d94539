"""``roslink-mqtt-broker`` as a process: reload on SIGHUP, login throttling, TLS, clean exit, clear errors."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support.broker_client import REFUSED, Probe
from tests.support.broker_setup import write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.net import free_port
from tests.support.procs import CONFIG, DEMO_PASSWORDS, ROOT
from tests.support.waits import paced, wait_until

PW = DEMO_PASSWORDS
BOB_GRANT = "    grants:\n      - {key: demo-key-turtle1, role: viewer}\n"


@pytest.fixture
def probes() -> Iterator:
    made: list[Probe] = []

    def make(port: int, login: str, password: str | None = None, **kw) -> Probe:
        p = Probe(port, login, password or PW[login], **kw)
        made.append(p)
        return p

    yield make
    for p in made:
        p.close()


def _broker_cli(*args: str, timeout: float = 20) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.broker", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def _wait_logged(broker, text: str, timeout: float) -> None:
    """Until the broker's log says ``text``; failing, show the log's tail."""
    try:
        wait_until(f"the broker to log {text!r}", lambda: text in broker.output(), timeout=timeout)
    except AssertionError as e:
        raise AssertionError(f"{e}\n{broker.output()[-2000:]}") from None


# -- SIGHUP reload -----------------------------------------------------------------------------


def test_sighup_revokes_bobs_grant_at_once_and_closes_only_his_connections(tmp_path: Path, probes) -> None:
    """bob loses turtle1: deliveries to him stop at once and his connection is closed (what he subscribed to ends
    with the grant: fleet apply's contract); alice, unchanged, keeps hers and her stream."""
    fleet = write_fleet(tmp_path, read_only_service=False)
    assert fleet.read_text().count(BOB_GRANT) == 1
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        bob, alice, robot = (probes(broker.port, login) for login in ("bob", "alice", "turtle1"))
        for p in (bob, alice, robot):
            assert p.connect() == 0
        assert bob.subscribe("roslink/turtle1/state/#") == [1]
        assert alice.subscribe("roslink/turtle1/state/#") == [1]
        stop = threading.Event()

        def stream() -> None:  # turtle1 state at 50 Hz, until stopped
            for i in paced(0.02, within=120, stop=stop.is_set):
                robot.client.publish("roslink/turtle1/state/robot_status", str(i), qos=0)

        streamer = threading.Thread(target=stream)
        streamer.start()
        try:
            bob.wait_for(lambda m: True, timeout=5)
            fleet.write_text(fleet.read_text().replace(BOB_GRANT, "    grants: []\n"))
            hup_at = time.monotonic()
            broker.signal(signal.SIGHUP)
            after = bob.drain(2.0)  # everything bob still gets from here on
            alice_after = [m for m in alice.drain(0.3) if m.at > hup_at + 1.0]
        finally:
            stop.set()
            streamer.join()
        last = max((m.at for m in after), default=hup_at) - hup_at
        record_measurement("broker: last delivery to bob after SIGHUP", last, 1.0)
        assert last < 1.0, f"bob still received turtle1 state {last:.2f} s after SIGHUP"
        assert not [m for m in after if m.at > hup_at + 1.0]
        assert alice_after or alice.drain(0.5), "alice (unchanged) stopped receiving"
        assert bob.disconnected.is_set(), "bob kept his connection"
        assert not alice.disconnected.is_set(), "alice lost hers"
        assert "fewer grants ['bob']; 1 connection(s) dropped" in broker.output()
        # bob may log in again, but a fresh subscription of his to turtle1 is refused now
        again = probes(broker.port, "bob")
        assert again.connect() == 0 and again.subscribe("roslink/turtle1/state/#") == [128]


def test_reload_with_a_broken_file_keeps_the_running_rules_and_removed_logins_are_dropped(tmp_path: Path,
                                                                                           probes) -> None:
    fleet = write_fleet(tmp_path, read_only_service=False)
    good = fleet.read_text()
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        carol = probes(broker.port, "carol")
        assert carol.connect() == 0
        fleet.write_text(good.replace("system_id: 1", "system_id: one"))
        broker.signal(signal.SIGHUP)
        wait_until("the broker to refuse the reload", lambda: "reload refused" in broker.output(), timeout=10)
        assert "reload refused" in broker.output() and "system_id" in broker.output()
        assert not carol.disconnected.is_set()
        assert carol.subscribe("roslink/turtle2/state/#") == [1]  # old rules still enforced

        # carol removed from the fleet: her connection goes at once, her login no longer works
        start = good.index("  carol:")
        end = good.index("  admin:")
        fleet.write_text(good[:start] + good[end:])
        broker.signal(signal.SIGHUP)
        assert carol.disconnected.wait(5), "a removed login stayed connected"
        again = probes(broker.port, "carol")
        assert again.connect() == REFUSED


# -- failed-login throttling ---------------------------------------------------------------------


def test_failed_logins_are_slowed_per_address_without_locking_anyone_out(tmp_path: Path, probes) -> None:
    with EmbeddedBrokerProcess(tmp_path, CONFIG, "--login-free-failures", "2", "--login-max-delay", "1") as broker:
        durations = []
        for _ in range(5):  # guessing from 127.0.0.2
            start = time.monotonic()
            assert probes(broker.port, "admin", "guess", bind_address="127.0.0.2").connect() == REFUSED
            durations.append(time.monotonic() - start)
        # the first failures are free, then every attempt waits for its slot (0.5 s and up): compared with each
        # other, not with a wall-clock figure, since a password check on a busy machine may take 0.3 s by itself
        assert max(durations[:2]) < min(durations[2:]), durations
        assert min(durations[2:]) >= 0.4, durations
        assert sum(durations) >= 2.0, durations

        start = time.monotonic()  # somebody else, same broker, another address: not affected
        assert probes(broker.port, "alice", bind_address="127.0.0.3").connect() == 0
        assert time.monotonic() - start < min(durations[2:]), durations

        start = time.monotonic()  # the right password from the guessing address: slowed, not blocked
        assert probes(broker.port, "admin", bind_address="127.0.0.2").connect() == 0
        assert 0.4 <= time.monotonic() - start < 5
        assert "refused client_id=" in broker.output() and "wrong password" in broker.output()


def _connect_packet(client_id: str, username: str, password: str) -> bytes:
    """An MQTT 3.1.1 CONNECT (clean session, user name and password), built here so that dozens can be written
    in the same millisecond: a client library connects one at a time."""
    def text(value: str) -> bytes:
        data = value.encode()
        return len(data).to_bytes(2, "big") + data

    body = text("MQTT") + bytes([4, 0b11000010]) + (30).to_bytes(2, "big")
    body += text(client_id) + text(username) + text(password)
    return bytes([0x10, len(body)]) + body  # every body here is under 128 bytes: one length byte


def test_a_fleet_connecting_at_once_from_one_address_is_let_in(tmp_path: Path) -> None:
    """Every login of the demo fleet six times over, CONNECTs written in the same moment from 127.0.0.1, as a
    fleet behind one NAT does after a broker restart (no login known good yet): checked a few at a time,
    nobody refused. (They used to count as failed logins until answered: most of them were refused.)"""
    logins = [login for login in DEMO_PASSWORDS for _ in range(6)]
    with EmbeddedBrokerProcess(tmp_path, CONFIG) as broker:
        sockets = [socket.create_connection(("127.0.0.1", broker.port), timeout=10) for _ in logins]
        try:
            start = time.monotonic()
            for i, (sock, login) in enumerate(zip(sockets, logins, strict=True)):
                sock.sendall(_connect_packet(f"{login}-at-once-{i}", login, DEMO_PASSWORDS[login]))
            codes = []
            for sock in sockets:
                connack = b""
                while len(connack) < 4:
                    chunk = sock.recv(4 - len(connack))
                    if not chunk:
                        break
                    connack += chunk
                codes.append(connack[3] if len(connack) == 4 else None)
            took = time.monotonic() - start
        finally:
            for sock in sockets:
                sock.close()
        assert codes == [0] * len(logins), list(zip(logins, codes, strict=True))
        assert took < 5, took  # milliseconds each, not the throttle's seconds


# -- process lifecycle ---------------------------------------------------------------------------


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_clean_exit_on_signal(tmp_path: Path, probes, sig: int) -> None:
    broker = EmbeddedBrokerProcess(tmp_path, CONFIG).start()
    try:
        client = probes(broker.port, "alice")
        assert client.connect() == 0
        start = time.monotonic()
        broker.signal(sig)
        assert broker.proc.wait(10) == 0
        assert time.monotonic() - start < 5
        assert client.disconnected.wait(5)
        out = broker.output()
        assert "connected client_id=" in out and "user='alice'" in out and "stopped" in out
        assert "Traceback" not in out
    finally:
        broker.kill()


def test_embedded_broker_process_restarts_on_the_same_port(tmp_path: Path, probes) -> None:
    broker = EmbeddedBrokerProcess(tmp_path, CONFIG).start()
    port = broker.port
    try:
        broker.kill()
        broker.start()
        assert broker.port == port
        assert probes(port, "bob").connect() == 0
    finally:
        broker.stop()


def test_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        done = _broker_cli("--config", str(CONFIG), "--port", str(port), "--ws-port", "0")
        assert done.returncode == 1
        assert f"tcp listener 127.0.0.1:{port}: address already in use" in done.stderr
        assert "Traceback" not in done.stderr

        tcp = free_port()  # the WebSocket port is the busy one: the TCP listener must not linger
        done = _broker_cli("--config", str(CONFIG), "--port", str(tcp), "--ws-port", str(port))
        assert done.returncode == 1
        assert f"ws listener 127.0.0.1:{port}: address already in use" in done.stderr


def test_bad_config_is_a_clear_error(tmp_path: Path) -> None:
    bad = tmp_path / "robots.yaml"
    bad.write_text(CONFIG.read_text().replace("system_id: 2", "system_id: 1"))
    done = _broker_cli("--config", str(bad), "--port", str(free_port()))
    assert done.returncode == 2
    assert f"{bad}:" in done.stderr and "system_id" in done.stderr
    done = _broker_cli("--config", str(tmp_path / "missing.yaml"))
    assert done.returncode == 2 and "missing.yaml" in done.stderr and "cannot read" in done.stderr
    done = _broker_cli("--port", "70000")
    assert done.returncode == 2 and "port must be 0..65535" in done.stderr


def test_console_script_is_installed() -> None:
    script = Path(sys.executable).parent / "roslink-mqtt-broker"
    done = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=20)
    assert done.returncode == 0 and "--ws-port" in done.stdout


# -- TLS listener ------------------------------------------------------------------------------------
def _tls_on_127_0_0_2(tmp_path: Path) -> tuple[int, Path]:
    """A self-signed certificate for 127.0.0.2 (standing for a public address) and a fleet whose TLS listener binds
    it on a free port: (that port, the fleet file)."""
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=127.0.0.2",
                    "-addext", "subjectAltName=IP:127.0.0.2", "-keyout", str(tmp_path / "key.pem"),
                    "-out", str(tmp_path / "cert.pem")], check=True, capture_output=True)
    tls_port = free_port()
    fleet = write_fleet(tmp_path, edit=lambda t: t.replace(
        "  ws_port: 0\n", f"  ws_port: 0\n  tls: {{host: 127.0.0.2, port: {tls_port}, certfile: cert.pem, "
                          "keyfile: key.pem}\n"))
    return tls_port, fleet



@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_tls_listener_when_the_config_names_a_certificate(tmp_path: Path, probes) -> None:
    """TLS on an address of its own (broker.tls.host, here 127.0.0.2 standing for a public one), plain MQTT on
    127.0.0.1 only: the TLS address answers MQTT over TLS and nothing else."""
    tls_port, fleet = _tls_on_127_0_0_2(tmp_path)
    with EmbeddedBrokerProcess(tmp_path, fleet) as broker:
        assert f"mqtts://127.0.0.2:{tls_port}" in broker.output()
        p = probes(tls_port, "alice", host="127.0.0.2")
        p.client.tls_set(ca_certs=str(tmp_path / "cert.pem"))
        assert p.connect() == 0
        assert p.subscribe("roslink/turtle2/#") == [128]  # same ACL on every listener
        bad = probes(tls_port, "alice", "wrong", host="127.0.0.2")
        bad.client.tls_set(ca_certs=str(tmp_path / "cert.pem"))
        assert bad.connect() == REFUSED
        for where in (("127.0.0.2", broker.port), ("127.0.0.1", tls_port)):  # plain MQTT beside TLS: not there
            with socket.socket() as s:
                assert s.connect_ex(where) != 0, f"something listens on {where}"
        assert probes(broker.port, "alice").connect() == 0  # plain MQTT on loopback, for local programs

    (tmp_path / "key.pem").unlink()
    done = _broker_cli("--config", str(fleet), "--port", str(free_port()), "--ws-port", "0")
    assert done.returncode == 1 and "broker.tls.keyfile: cannot read" in done.stderr


def _ca_and_server_cert(tmp_path: Path, name: str) -> tuple[Path, Path, Path]:
    """A throwaway CA ``name`` and a certificate for 127.0.0.1 it signed: (ca.pem, cert.pem, key.pem)."""
    d = tmp_path / name
    d.mkdir()

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], check=True, capture_output=True, cwd=d, timeout=60)

    openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", f"/CN={name}", "-keyout",
            "ca.key", "-out", "ca.pem")
    openssl("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout", "key.pem", "-out", "s.csr")
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
    openssl("x509", "-req", "-in", "s.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-days", "1",
            "-extfile", "san.ext", "-out", "cert.pem")
    return d / "ca.pem", d / "cert.pem", d / "key.pem"


def test_a_renewed_certificate_is_served_after_sighup_and_nobody_is_dropped(tmp_path: Path, probes) -> None:
    """certbot renews the broker's certificate (here: one from another CA, so the two can be told apart) and
    reloads the broker: new TLS connections get the new one at once, the clients connected before stay connected
    and keep receiving; a key that does not match the certificate is refused and the previous pair kept."""
    old_ca, old_cert, old_key = _ca_and_server_cert(tmp_path, "old-ca")
    new_ca, new_cert, new_key = _ca_and_server_cert(tmp_path, "new-ca")
    shutil.copy(old_cert, tmp_path / "cert.pem")
    shutil.copy(old_key, tmp_path / "key.pem")
    tls_port = free_port()
    fleet = write_fleet(tmp_path, edit=lambda t: t.replace(
        "  ws_port: 0\n", f"  ws_port: 0\n  tls: {{port: {tls_port}, certfile: cert.pem, keyfile: key.pem}}\n"))

    def tls_probe(ca: Path, login: str = "alice") -> Probe:
        p = probes(tls_port, login)
        p.client.tls_set(ca_certs=str(ca))
        return p

    def refused_by_tls(ca: Path) -> bool:
        try:
            tls_probe(ca).connect(timeout=5)
        except ssl.SSLError:
            return True
        return False

    with EmbeddedBrokerProcess(tmp_path, fleet, "--log-level", "INFO") as broker:
        before = tls_probe(old_ca)
        assert before.connect() == 0
        assert before.subscribe("roslink/turtle1/state/#") == [1]
        shutil.copy(new_cert, tmp_path / "cert.pem")  # renewed in place, as certbot does
        shutil.copy(new_key, tmp_path / "key.pem")
        broker.signal(signal.SIGHUP)
        _wait_logged(broker, "reloaded the TLS certificate", timeout=10)
        after = tls_probe(new_ca)
        assert after.connect() == 0  # the new certificate, at once
        assert refused_by_tls(old_ca)  # and not the old one any more
        with Probe(broker.port, "turtle1", PW["turtle1"]) as robot:  # the connection made before is still there
            assert robot.connect() == 0
            robot.publish("roslink/turtle1/state/battery", b"{}", qos=1)
            assert before.wait_for(lambda m: m.topic == "roslink/turtle1/state/battery", timeout=10)
        shutil.copy(old_key, tmp_path / "key.pem")  # a key of another certificate: refused, nothing changes
        broker.signal(signal.SIGHUP)
        _wait_logged(broker, "not taken, still serving the previous one", timeout=10)
        assert tls_probe(new_ca).connect() == 0


def test_a_tls_only_broker_listens_in_clear_text_nowhere(tmp_path: Path, probes) -> None:
    """``port: 0`` (here the command line's ``--port 0``) and no WebSocket: the broker's only listener is TLS on its
    address (127.0.0.2 standing for a public one); a TLS client logs in, and the broker holds no other listening
    socket."""
    from roslink_mqtt.localproc import LocalProcess, wait_for_port

    tls_port, fleet = _tls_on_127_0_0_2(tmp_path)
    broker = LocalProcess([sys.executable, "-m", "roslink_mqtt.broker", "--config", str(fleet), "--port", "0",
                           "--ws-port", "0", "--log-level", "INFO"], tmp_path / "broker.log", cwd=ROOT)
    broker.spawn()
    try:
        wait_for_port(tls_port, 15, host="127.0.0.2")
        said = f"listening on mqtts://127.0.0.2:{tls_port}; fleet"
        _wait_logged(broker, said, timeout=15)  # the port answers a moment before the line is written
        p = probes(tls_port, "alice", host="127.0.0.2")
        p.client.tls_set(ca_certs=str(tmp_path / "cert.pem"))
        assert p.connect() == 0
        assert _listening_ports(broker.pid) == {tls_port}  # nothing else of the broker's listens, anywhere
    finally:
        broker.stop()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl not installed")
def test_each_listener_binds_its_own_address_and_wss_carries_mqtt(tmp_path: Path, probes) -> None:
    """Four listeners, three addresses: plain MQTT on 127.0.0.1 (``host``), WebSocket on 127.0.0.3 (``ws_host``),
    TLS and secure WebSocket on 127.0.0.2 (``tls.host``, ``tls.ws_port``). Each answers on its own address only,
    and a client logs in over ``wss://`` trusting the certificate."""
    tls_port, fleet = _tls_on_127_0_0_2(tmp_path)
    ws_port, wss_port = free_port(), free_port()
    text = fleet.read_text().replace("  ws_port: 0\n", f"  ws_port: {ws_port}\n  ws_host: 127.0.0.3\n", 1)
    fleet.write_text(text.replace("keyfile: key.pem}", f"keyfile: key.pem, ws_port: {wss_port}}}", 1))
    with EmbeddedBrokerProcess(tmp_path, fleet, "--ws-port", str(ws_port)) as broker:
        log = broker.output()
        for url in (f"mqtt://127.0.0.1:{broker.port}", f"ws://127.0.0.3:{ws_port}", f"mqtts://127.0.0.2:{tls_port}",
                    f"wss://127.0.0.2:{wss_port}"):
            assert url in log, log
        where = {broker.port: "127.0.0.1", ws_port: "127.0.0.3", tls_port: "127.0.0.2", wss_port: "127.0.0.2"}
        for port, address in where.items():
            for other in ("127.0.0.1", "127.0.0.2", "127.0.0.3"):
                with socket.socket() as probe:
                    assert (probe.connect_ex((other, port)) == 0) is (other == address), (port, other)
        secure = probes(wss_port, "alice", host="127.0.0.2", transport="websockets")
        secure.client.tls_set(ca_certs=str(tmp_path / "cert.pem"))
        assert secure.connect() == 0
        assert secure.subscribe("roslink/turtle2/#") == [128]  # the same ACL on every listener


def _listening_ports(pid: int | None) -> set[int]:
    """The TCP ports process ``pid`` listens on (its sockets among the machine's listening ones)."""
    from roslink_mqtt.localproc import listening_sockets

    assert pid is not None
    fds = {os.readlink(fd) for fd in Path(f"/proc/{pid}/fd").iterdir()}
    return {port for inode, port in listening_sockets().items() if inode in fds}


def test_a_public_plain_listener_and_the_demo_passwords_are_refused_at_start(tmp_path: Path) -> None:
    """The demo fleet copied to a server and started on every interface: the broker refuses before it listens (plain
    MQTT would carry passwords in clear text, and the demo's published passwords let anybody in); `fleet` says so."""
    from roslink_mqtt.localproc import fleet_copy

    port = free_port()
    started = subprocess.run([sys.executable, "-m", "roslink_mqtt.broker", "--config", str(CONFIG), "--host", "0.0.0.0",
                              "--port", str(port), "--ws-port", "0"], cwd=ROOT, capture_output=True, text=True,
                             timeout=30)
    assert started.returncode == 2, started.stderr
    assert "refused to start: broker.host 0.0.0.0 is not loopback, and plain MQTT would carry" in started.stderr
    assert "turtle1, turtle2, alice, bob, carol, admin still log in with the demo fleet's published" in started.stderr
    with socket.socket() as probe:
        assert probe.connect_ex(("127.0.0.1", port)) != 0, "it listened anyway"
    public = fleet_copy(tmp_path / "robots.yaml", CONFIG, edit=lambda d: d["broker"].update(host="0.0.0.0"))
    checked = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "fleet", "--config", str(public)],
                             cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert checked.returncode == 2 and "the broker would refuse to start: broker.host 0.0.0.0" in checked.stderr
