"""The bridge's MQTT connection: dial out, stay connected, never block ROS.

paho runs its own network thread. Callbacks here only hand data over; the
ROS side publishes from that thread (rclpy publishers are thread-safe) and
MQTT publishes from the executor are queued by paho, so neither side ever
waits for the other.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import paho.mqtt.client as mqtt

from ...mqtt import (
    WRONG_LOGIN,
    BrokerRing,
    BrokerUrl,
    closed_before_connack,
    connack_refusal,
    login_refused,
    make_client,
    parse_broker_urls,
)
from . import trace
from .intake import Intake
from .ping_ledger import PingLedger

log = logging.getLogger("roslink_mqtt.bridge.core.link")

FIRST_RETRY = 0.1  # s before the first retry of an unreachable broker; doubled per attempt up to the link's cap
# s before retrying a refused login, doubled per refusal up to REFUSED_RETRY_MAX: the same password is refused again
# until someone changes it, and every refusal counts against the broker's throttle of failed logins from the robot's
# address (slowing down every other login from there, a NAT's or a gateway's included)
REFUSED_RETRY_FIRST, REFUSED_RETRY_MAX = 5.0, 60.0


def worth_logging(attempt: int) -> bool:
    """Which failed attempts in a row are logged: the first three, every fifth for a while, then every thirtieth
    (at the 2 s cap: every 10 s for the first two minutes, then once a minute)."""
    return attempt <= 3 or (attempt <= 60 and attempt % 5 == 0) or attempt % 30 == 0


def bridge_client_id(robot: str, purpose: str = "") -> str:
    """``roslink-bridge-<robot>-<64 random bits>`` (``-<purpose>-`` before the bits), new at every start.

    On a broker where any login may take over any client id (Mosquitto, MQTT itself), a
    predictable id let a viewer keep the robot offline by connecting with it in a loop. The
    embedded broker scopes client ids by login anyway; the bridge uses a clean session, so
    nothing depends on the id staying the same across restarts.
    """
    return f"roslink-bridge-{robot}-{purpose + '-' if purpose else ''}{secrets.token_hex(8)}"


class MqttLink:
    """One paho client with reconnects; ``on_message(topic, payload, retained, arrived)`` runs on paho's thread.

    ``arrived`` is ``time.monotonic()`` when paho handed the message over: the bridge measures from it how long
    a command waited inside the bridge before reaching ROS.
    """

    def __init__(self, *, client_id: str, username: str, password: str | None, url: BrokerUrl | Sequence[BrokerUrl],
                 keepalive: int, will: tuple[str, bytes] | None, subscriptions: Callable[[], list[tuple[str, int]]],
                 on_message: Callable[[str, bytes, bool, float], None],
                 on_up: Callable[[], None] = lambda: None, on_down: Callable[[str], None] = lambda reason: None,
                 ca_file: str | None = None, max_reconnect_delay: float = 2.0, max_payload: int = 0,
                 report: bool = False, on_refused: Callable[[str], None] = lambda reason: None,
                 intake: Intake | None = None) -> None:
        """``url``: one broker or a cluster's nodes (failover: a failed or lost connection moves to the next).
        ``max_payload``: the broker's message size limit (robots.yaml ``broker.max_payload``; 0 = none).
        ``report``: this link says in the log why it is not connected (unreachable, refused login), at WARNING and
        ERROR; the bridge's other links, dialling the same broker with the same login, say it at DEBUG only.
        ``on_refused(reason)``: called (on the network thread) at every refused login.
        ``intake``: the most messages a second this link reads (bridge/core/intake.py; None: as fast as they come)."""
        urls = parse_broker_urls(url)
        self.username, self.report, self._on_refused = username, report, on_refused
        self.max_reconnect_delay = max_reconnect_delay
        self.failures = 0  # connection attempts that failed in a row (unreachable, closed, refused)
        self.refusals = 0  # of them, refused logins in a row
        self._closed_reason: str | None = None  # why the broker hangs up before CONNACK (probed once)
        self._answered = False  # a CONNACK came on this connection (so its end needs no explaining)
        self.keepalive, self.max_payload = keepalive, max_payload
        self.client_id = client_id  # named in the log: a bridge has several connections, one may drop alone
        self._oversized: set[str] = set()  # topics already logged for an oversized message
        self._subscriptions, self._on_message, self._on_up, self._on_down = subscriptions, on_message, on_up, on_down
        self.connected = threading.Event()
        self.subscribed = threading.Event()  # the broker acknowledged this connection's subscriptions
        self._subscribe_mid: int | None = None
        self.client = make_client(client_id, username=username, password=password, url=urls, ca_file=ca_file,
                                  max_reconnect_delay=max_reconnect_delay)
        self.brokers = BrokerRing(self.client, urls)
        if will is not None:
            self.set_will(*will)
        self.client.on_connect = self._handle_connect
        self.client.on_disconnect = self._handle_disconnect
        self.client.on_message = self._handle_message
        self.client.on_connect_fail = self._handle_connect_fail
        self.client.on_subscribe = self._handle_subscribe
        self.closing = False  # stop() asked for the disconnect: it is a shutdown, not a lost broker
        self._heard_at = 0.0  # time.monotonic() of the broker's last message (the link check's "slow, not silent")
        self._intake, self._intake_told = intake, False
        # s a message handed over now waits in the network; the uplink (bridge/core/uplink_sender.py) replaces it
        self.queue_delay: Callable[[], float] = lambda: 0.0
        # the uplink's end-to-end probe (bridge/core/path_meter.py): called with time.monotonic() on paho's thread
        # when a PINGRESP arrives (paho 2.2 has no callback for it: its handler is wrapped; paho is pinned)
        self.on_pong: Callable[[float], None] | None = None
        # every PINGREQ of the connection in order, and which are probes: only a probe's answer is its round trip
        self._pings = PingLedger()
        handle_pingresp = self.client._handle_pingresp
        self._send_pingreq = self.client._send_pingreq

        def pingreq() -> mqtt.MQTTErrorCode:  # paho's own, for the keep-alive (paho's thread)
            return self._queue_ping(probe=False)

        def pingresp() -> mqtt.MQTTErrorCode:
            ours = self._pings.answer()
            rc = handle_pingresp()
            if ours and self.on_pong is not None and rc == mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
                self.on_pong(time.monotonic())
            return rc

        self.client._send_pingreq = pingreq  # type: ignore[method-assign]
        self.client._handle_pingresp = pingresp  # type: ignore[method-assign]

    @property
    def url(self) -> BrokerUrl:
        """The broker we are connected to (or trying next)."""
        return self.brokers.url

    def set_password(self, password: str) -> None:
        """Use ``password`` from the next connection on (a rotated robot password, SIGHUP); this one stays."""
        self.client.username_pw_set(self.username, password)

    def set_will(self, topic: str, payload: bytes) -> None:
        """The retained last-will the broker publishes if we vanish; before :meth:`start` (it goes with CONNECT)."""
        self.client.will_set(topic, payload, qos=1, retain=True)

    # -- lifecycle ------------------------------------------------------------
    def start(self) -> None:
        """Connect in the background; retries forever (start order does not matter)."""
        self.client.connect_async(self.url.host, self.url.port, keepalive=self.keepalive)
        self.client.loop_start()

    def stop(self, last_words: Sequence[tuple[str, bytes, int, bool]] = ()) -> None:
        """Publish ``last_words`` (e.g. the offline heartbeat), then disconnect cleanly.

        Sets :attr:`closing` first, so the disconnect that follows is logged (and reported to ``on_down``) as
        the shutdown it is: a clean Ctrl-C must not read like a network failure in the log.
        """
        self.closing = True
        if self.connected.is_set():
            infos = [self.client.publish(t, p, qos=q, retain=r) for t, p, q, r in last_words]
            for info in infos:
                try:
                    info.wait_for_publish(timeout=1.0)
                except (RuntimeError, ValueError):
                    pass
        self.client.disconnect()
        self.client.loop_stop()

    # -- traffic ----------------------------------------------------------------
    def publish(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> mqtt.MQTTMessageInfo | None:
        """Queue a message; dropped (not queued) while disconnected, so stale state is never replayed.

        A message larger than the broker accepts is dropped here and logged once per topic: sent, it would make
        the broker close the connection (both brokers do), and the robot would lose its link — commands, stops
        and heartbeats with it — once per message.
        """
        if self.max_payload and len(payload) > self.max_payload:
            if topic not in self._oversized and len(self._oversized) < 256:
                self._oversized.add(topic)
                log.warning("not publishing %s: %d bytes > the broker's max_payload %d (robots.yaml broker."
                            "max_payload); a smaller encoding (cbor), a lower max_rate upstream or a larger limit "
                            "would let it through", topic, len(payload), self.max_payload)
            return None
        if self.connected.is_set():
            if trace.TRACE is not None:
                trace.TRACE.mark("mqtt_out", topic)
            return self.client.publish(topic, payload, qos=qos, retain=retain)
        return None

    def ping(self) -> bool:
        """Send a PINGREQ now: the uplink's probe of the whole path, since the broker's PINGRESP can only come once
        the PINGREQ has passed every queue before it, including those of hops that acknowledge at once. False when
        not connected. Paho's keep-alive still holds: its PINGRESP deadline runs from the last PINGREQ sent, and
        the uplink sends one only once the last was answered, so a dead path is still found within keep-alive."""
        if not self.connected.is_set():
            return False
        if self._queue_ping(probe=True) != mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
            return False
        if self._pings.none_waiting():
            # answered before paho marked it out (see bridge/core/ping_ledger.py): no PINGREQ waits, and a mark left
            # set would make paho's keep-alive drop a healthy connection once probing pauses
            self.client._ping_t = 0
        return True

    def heard_at(self) -> float:
        """``time.monotonic()`` when the broker's last message arrived (0.0: none yet)."""
        return self._heard_at

    def heard_while_writing(self) -> None:
        """Count this moment as hearing from the broker, for paho's keep-alive: the caller knows the broker is
        there (the path's probes on another connection are answered) and sees this connection's bytes leave.

        Why: paho drops a connection that receives nothing for ``keepalive`` s after its PINGREQ, and a PINGREQ
        queues behind the message being written. On a paced lane that message may be a 300 kB camera frame at
        8 kB/s, or a 4 MB map at what the other lanes leave: its connection received nothing for longer than any
        keep-alive, and paho dropped it mid-message, the message lost (in 4 runs of the hidden-hop test in 5; the
        lane reconnected and the path meter started over). A connection whose writes stop going out is still
        dropped as before: its caller sees no progress and stops calling this."""
        client = self.client
        with client._msgtime_mutex:
            client._last_bytes_received = time.monotonic()  # paho's own clock (time_func) is monotonic

    def _queue_ping(self, probe: bool) -> mqtt.MQTTErrorCode:
        """Queue a PINGREQ, entered in the ledger first (its answer may come before this thread's next line)."""
        number = self._pings.sending(probe)
        rc = self._send_pingreq()
        if rc != mqtt.MQTTErrorCode.MQTT_ERR_SUCCESS:
            self._pings.not_sent(number)
        return rc

    def subscribe(self, topic: str, qos: int = 1) -> None:
        """Add a subscription now; after a reconnect ``subscriptions()`` must list it too."""
        if self.connected.is_set():
            self.client.subscribe(topic, qos)

    def unsubscribe(self, topic: str) -> None:
        if self.connected.is_set():
            self.client.unsubscribe(topic)

    # -- paho callbacks (network thread) ------------------------------------------
    def _retry_in(self, delay: float) -> None:
        """The next connection attempt in ``delay`` s (paho waits that long before it dials again)."""
        # paho annotates the delays int, but they are seconds used as numbers (a float works)
        self.client.reconnect_delay_set(min_delay=delay, max_delay=delay)  # type: ignore[arg-type]

    def _attempt_failed(self, what: str) -> None:
        """An unreachable broker, or one that hung up or turned us away for a reason other than the login: retry
        soon (FIRST_RETRY, doubling up to max_reconnect_delay), and say so now and then."""
        self.failures += 1
        self.refusals = 0
        delay = min(FIRST_RETRY * 2 ** min(self.failures - 1, 30), self.max_reconnect_delay)
        self._retry_in(delay)
        failed = self.url
        nxt = self._move_on()
        level = logging.WARNING if self.report and worth_logging(self.failures) else logging.DEBUG
        log.log(level, "broker %s %s, retrying (attempt %d, next in %.1f s%s)", failed, what, self.failures, delay,
                f" with {nxt}" if nxt else "")

    def _handle_connect(self, client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        self._answered = True
        self._pings.reset()  # a new connection: nothing of the old one will be answered
        if reason.is_failure:
            if not login_refused(reason):
                self._attempt_failed(f"refused the connection ({connack_refusal(reason)})")
                return
            self.failures += 1
            self.refusals += 1
            delay = min(REFUSED_RETRY_FIRST * 2 ** min(self.refusals - 1, 30), REFUSED_RETRY_MAX)
            self._retry_in(delay)
            refused = self.url
            nxt = self._move_on()
            log.log(logging.ERROR if self.report else logging.DEBUG,
                    "broker %s refused %s's login: %s (the robot's password: ROSLINK_PASSWORD, --password-file or "
                    "bridge.password_file); retrying in %.0f s%s (refusal %d; slowly: each one counts against the "
                    "broker's throttle of failed logins from this address)", refused, self.username, WRONG_LOGIN,
                    delay, f" with {nxt}" if nxt else "", self.refusals)
            if self.report:
                self._on_refused(f"broker {refused} refused {self.username}'s login: {WRONG_LOGIN}")
            return
        if self.failures and self.report:
            log.info("connected to %s after %d failed attempts", self.url, self.failures)
        self.failures = self.refusals = 0
        self.client.reconnect_delay_set(min_delay=FIRST_RETRY,  # type: ignore[arg-type]
                                        max_delay=self.max_reconnect_delay)  # type: ignore[arg-type]
        subs = self._subscriptions()
        if subs:
            _, self._subscribe_mid = client.subscribe(subs)
        else:
            self.subscribed.set()
        self.connected.set()
        log.info("connected to %s", self.url)
        self._on_up()

    def _handle_disconnect(self, _client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        was_up = self.connected.is_set()
        self.connected.clear()
        self.subscribed.clear()
        answered, self._answered = self._answered, False
        if not was_up:
            if not self.closing and not answered:  # a refused CONNACK has said why already
                self._closed_before_connack(reason)
            return
        if self.closing:
            log.info("disconnected from %s (shutting down)", self.url)
        else:
            lost = self.url
            nxt = self._move_on()
            log.warning("lost the broker %s (%s, connection %s); reconnecting%s", lost, reason, self.client_id,
                        f" to {nxt}" if nxt else "")
        self._on_down(str(reason))

    def _handle_subscribe(self, _client: mqtt.Client, _userdata: Any, mid: int, _reason_codes: Any,
                          _props: Any) -> None:
        if mid == self._subscribe_mid:
            self.subscribed.set()

    def _closed_before_connack(self, reason: object) -> None:
        """The connection ended before any CONNACK: paho's keep-alive gave up on a slow answer (a broker's login
        throttle holds one after failed logins), or the broker hung up on our CONNECT (a TLS port, say)."""
        if str(reason) == "Keep alive timeout":
            self._attempt_failed(f"did not answer the login within {self.keepalive} s (the keep-alive)")
            return
        if self._closed_reason is None:  # asked once: the answer does not change while the URL does not
            self._closed_reason = closed_before_connack(self.url) if self.report else "it hung up"
        self._attempt_failed(f"closed the connection without answering: {self._closed_reason}")

    def _handle_connect_fail(self, _client: mqtt.Client, _userdata: Any) -> None:
        self._attempt_failed("unreachable")

    def _move_on(self) -> BrokerUrl | None:
        """Failover: the next connection attempt goes to the next broker of the list (None: only one)."""
        return None if self.closing else self.brokers.advance()

    def _pace_intake(self) -> None:
        """Wait for this message's turn (bridge/core/intake.py): paho's thread sleeps, so this connection's socket fills
        and the broker holds the rest; said once per link."""
        assert self._intake is not None
        delay = self._intake.wait(time.monotonic())
        if delay <= 0.0:
            return
        if not self._intake_told:
            self._intake_told = True
            log.warning("more than %g messages a second of %s: the bridge reads them at that rate, the rest waits at "
                        "the broker (a backlog longer than keepalive %d s resets this connection, dropping it)",
                        self._intake.rate, self._intake.what, self.keepalive)
        time.sleep(delay)

    def _handle_message(self, _client: mqtt.Client, _userdata: Any, message: mqtt.MQTTMessage) -> None:
        # Taken first thing: the command path compares it with the time of publication to ROS, so a command
        # that waited too long inside the bridge (lock, backlog) is never executed late.
        if self._intake is not None:
            self._pace_intake()
        arrived = time.monotonic()
        self._heard_at = arrived
        if trace.TRACE is not None:
            trace.TRACE.mark("mqtt_in", message.topic)
        try:
            # paho types payload bytes | bytearray; a received message's is always bytes (struct.unpack)
            self._on_message(message.topic, message.payload, bool(message.retain), arrived)  # type: ignore[arg-type]
        except Exception:  # a bug in one handler must not kill the network thread
            log.exception("error handling %s", message.topic)
