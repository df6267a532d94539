"""Pure logic of tests/integration/test_failover.py: no processes, no sockets."""

from __future__ import annotations

import pytest

from roslink_mqtt.mqtt import parse_broker_urls


def test_a_list_of_brokers_parses_and_refuses_mixed_schemes() -> None:
    urls = parse_broker_urls("mqtt://a:1883, mqtt://b:1884,mqtt://c")
    assert [(u.host, u.port) for u in urls] == [("a", 1883), ("b", 1884), ("c", 1883)]
    assert parse_broker_urls(["mqtts://a", "mqtts://b:9883"])[1].port == 9883
    with pytest.raises(ValueError, match="mix schemes"):
        parse_broker_urls("mqtts://a,mqtt://b")
    with pytest.raises(ValueError, match="no broker URL"):
        parse_broker_urls(" , ")


# -- what a refused or silent broker is called (roslink_mqtt.mqtt: one wording for the CLI, SDK, bridge, dashboard) --

def test_a_refused_login_reads_the_same_from_either_code() -> None:
    from roslink_mqtt.mqtt import WRONG_LOGIN, connack_refusal, login_refused

    assert WRONG_LOGIN == "wrong username or password"
    for code in (4, 5, 134, 135):  # MQTT 3.1.1 return codes, and paho's reason codes for them
        assert connack_refusal(code) == WRONG_LOGIN and login_refused(code)
    assert connack_refusal(3) == connack_refusal(136) == "the broker is unavailable" and not login_refused(136)


def test_clients_wait_longer_for_a_login_than_the_broker_may_hold_it() -> None:
    from roslink_mqtt.broker.ratelimit import LoginThrottle
    from roslink_mqtt.mqtt import LOGIN_WAIT

    throttle = LoginThrottle()
    assert LOGIN_WAIT > throttle.max_wait >= throttle.by_address.max_delay  # else a slowed verdict reads "no answer"


def test_a_plain_url_at_a_tls_port_is_told_so(tmp_path) -> None:
    import shutil
    import socket
    import ssl
    import subprocess
    import threading

    import pytest

    from roslink_mqtt.mqtt import closed_before_connack, parse_broker_url, speaks_tls

    if shutil.which("openssl") is None:
        pytest.skip("openssl not installed")
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=x",
                    "-keyout", str(tmp_path / "k.pem"), "-out", str(tmp_path / "c.pem")],
                   check=True, capture_output=True)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(tmp_path / "c.pem", tmp_path / "k.pem")
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            try:
                with context.wrap_socket(conn, server_side=True):
                    pass
            except OSError:
                pass

    threading.Thread(target=serve, daemon=True).start()
    try:
        assert speaks_tls("127.0.0.1", port)
        assert closed_before_connack(parse_broker_url(f"mqtt://127.0.0.1:{port}")) == \
            f"this port speaks TLS: use mqtts://127.0.0.1:{port}"
        assert closed_before_connack(parse_broker_url(f"ws://127.0.0.1:{port}/mqtt")).endswith(
            f"use wss://127.0.0.1:{port}/mqtt")
    finally:
        server.close()
    plain = socket.create_server(("127.0.0.1", 0))
    try:
        assert not speaks_tls("127.0.0.1", plain.getsockname()[1], timeout=0.3)  # listens, never answers a hello
    finally:
        plain.close()
