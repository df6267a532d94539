"""The amqtt sources the embedded broker depends on are the ones its fixes were written against.

``roslink_mqtt/broker/hardened.py`` (and guard.py, plugins.py, main.py) override, wrap, call or read amqtt 0.12.1
internals: private methods, instance attributes made in ``__init__``, the order in which the stock broker calls
them. An amqtt upgrade can change any of these without breaking an import, and a fix then stops working silently
(or, worse, half works). So the source text of each one is hashed (sha256 of ``inspect.getsource``) and compared
with what was recorded in ``amqtt_fingerprint.json``: a change, a removal or a new amqtt version fails here, with
the names to re-diff. Instance data (``_sessions``, ``_puback_waiters``...) is fingerprinted through the method
that creates it.

After re-diffing every reported name against the fix that relies on it (broker/FIXES.md says which), record the
new sources: ``python -m tests.unit.test_amqtt_fingerprint --write``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
import tomllib
from collections.abc import Mapping
from pathlib import Path

import pytest

from tests.support.fingerprint import CHANGED, GONE, UNLISTED, differences, digest, fingerprints, report, source_of

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]
RECORD = Path(__file__).with_name("amqtt_fingerprint.json")
WRITE = "python -m tests.unit.test_amqtt_fingerprint --write"

# ``module:qualified.name`` -> why we depend on it. A name resolves only in the class that defines it itself, so a
# method that moves to another class counts as gone: whoever calls it may have changed too.
RELIED_ON: dict[str, str] = {
    # -- amqtt.broker.Broker: overridden or wrapped by HardenedBroker
    "amqtt.broker:Broker.__init__": "creates _sessions, _broadcast_queue, _tasks_queue, _servers, plugins_manager "
                                    "(read by hardened.py), and _subscriptions, _retained_messages (replaced by "
                                    "our tables right after it: fix 24)",
    "amqtt.broker:Broker.start": "wrapped (fix 12); its 'Broker startup failed' log line is filtered by main.py",
    "amqtt.broker:Broker.shutdown": "wrapped (fix 30: connections still logging in are cancelled first); waits for "
                                    "its listeners to close",
    "amqtt.broker:Broker.ws_connected": "replaced (fix 15: SafeWebSocketsReader)",
    "amqtt.broker:Broker._create_ssl_context": "wrapped: the TLS listeners' contexts are kept so that SIGHUP gives "
                                               "them a renewed certificate (HardenedBroker.reload_certificates)",
    "amqtt.broker:Broker._start_listeners": "calls self._create_ssl_context(listener) once per TLS listener and "
                                            "hands the context to its server (a reload changes that object)",
    "amqtt.broker:Broker.stream_connected": "TCP connections reach our _client_connected through it (fix 14)",
    "amqtt.broker:Broker._client_connected": "wrapped (fix 14: the packet gate wraps the reader)",
    "amqtt.broker:Broker._initialize_client_session": "replaced (fixes 1, 4-7, 10, 27); the part after "
                                                      "authentication mirrors stock",
    "amqtt.broker:Broker._handle_client_session": "calls _authenticate after _initialize_client_session, takes "
                                                  "over, sends retained messages for every filter (fixes 2, 4, 5)",
    "amqtt.broker:Broker._client_message_loop": "dispatches to the _handle_* methods we wrap; False from "
                                                "_handle_message_delivery ends it; subscriptions before "
                                                "unsubscriptions (fix 31 queues both as one)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_unsubscribe": "replaced: queued with the "
                                                                                   "SUBSCRIBEs (fix 31)",
    "amqtt.mqtt.protocol.broker_handler:UnSubscription": "built by our handle_unsubscribe and the inline reader "
                                                         "(fixes 31, 32)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.__init__": "creates _pending_subscriptions, the one "
                                                                         "queue fix 31 uses for both",
    "amqtt.broker:Broker._authenticate": "replaced, and called unbound by HardenedBroker._admit (fix 4)",
    "amqtt.broker:Broker._handle_disconnect": "wrapped (fix 19); publishes the will on an abnormal disconnect",
    "amqtt.broker:Broker._handle_subscription": "replaced (fixes 2, 16)",
    "amqtt.broker:Broker._handle_unsubscription": "wrapped (fix 16: per-session filter count)",
    "amqtt.broker:Broker._handle_message_delivery": "wrapped (fixes 3, 13)",
    "amqtt.broker:Broker.retain_message": "wrapped (fixes 2, 18: quota); stores into _retained_messages as a "
                                          "mapping (fix 24: our RetainedTable)",
    "amqtt.broker:Broker.add_subscription": "called (fix 16); uses _subscriptions as a mapping (fix 24)",
    "amqtt.broker:Broker._topic_filtering": "replaced (fix 11); same semantics as stock required",
    "amqtt.broker:Broker._delete_session": "called (fixes 5, 6, 19)",
    "amqtt.broker:Broker._del_all_subscriptions": "iterates _subscriptions, deletes emptied filters (a mapping: "
                                                  "fix 24)",
    "amqtt.broker:Broker._del_subscription": "leaves an empty list in _subscriptions (our unsubscription wrapper "
                                             "prunes it)",
    "amqtt.broker:Broker._session_monitor": "reaps disconnected clean sessions once a second (fix 19 does it at once)",
    "amqtt.broker:Broker._broadcast_loop": "hands _tasks_queue to _run_broadcast, drops finished deliveries only at "
                                           "its front (fix 22); 'Task failed ...' lines filtered by main.py",
    "amqtt.broker:Broker._run_broadcast": "replaced (fixes 3, 8, 17, 22, 24, 25, 26)",
    "amqtt.broker:Broker._retain_broadcast_message": "wrapped (fix 20); reads the broadcast dict keys",
    "amqtt.broker:Broker._broadcast_message": "replaced (fix 3: adds the pub_qos key)",
    "amqtt.broker:Broker.internal_message_broadcast": "plugins' broadcast_message goes through it to "
                                                      "_broadcast_message",
    "amqtt.broker:Broker._publish_session_retained_messages": "replaced (fix 9)",
    "amqtt.broker:Broker._publish_retained_messages_for_subscription": "replaced by a no-op (fix 2)",
    "amqtt.broker:Broker._matches": "called; tests/unit/test_broker_subscriptions.py compares the tables with it",
    "amqtt.broker:Broker._get_handler": "called (fixes 2, 9, 17, 25, 26)",
    "amqtt.broker:Server.close_instance": "called on the servers of a failed start (fix 12)",
    "amqtt.broker:RetainedApplicationMessage": "its topic, data and qos are read when retained messages are sent",
    "amqtt.broker:BrokerContext": "plugins.py reads sessions, subscriptions, retained_messages and calls "
                                  "retain_message, broadcast_message",
    # -- protocol handlers: HardenedHandler overrides, the broker calls
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.init_from_connect": "replaced by connect.py's "
                                                                                  "read_connect (fix 33): the "
                                                                                  "same checks and answers",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_read_timeout": "replaced (fix 1: a no-op in "
                                                                                    "stock)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_connection_closed": "called to end a "
                                                                                         "connection (fixes 1, 5)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_disconnect": "None in the disconnect waiter = "
                                                                                  "abnormal: the will fires",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.mqtt_acknowledge_subscription": "called (fix 2)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.__init__": "creates reader, writer, session, _puback_waiters, "
                                                            "_pubrec_waiters, _pubcomp_waiters (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.start": "calls _retry_deliveries when a handler starts (fix 28), "
                                                         "after starting the reader (fix 32 waits for it)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._stop_waiters": "cancels the acknowledgement waiters; fix 28 "
                                                                 "keeps the message in inflight_out then",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._retry_deliveries": "replaced: resends inflight_out on resume "
                                                                     "(fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.mqtt_publish": "called for every delivery not written directly "
                                                                "(fix 25)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._handle_message_flow": "routes deliveries to the QoS flows we "
                                                                        "replace (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._handle_qos1_message_flow": "replaced for outgoing messages, called "
                                                                             "for incoming (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._handle_qos2_message_flow": "replaced for outgoing messages, called "
                                                                             "for incoming (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._reader_loop": "WebSocket connections (TCP: the inline reader, "
                                                                "fix 32): reads session.keep_alive once as its read "
                                                                "timeout, calls handle_read_timeout, ends on other "
                                                                "errors (fixes 1, 13, 14)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler._send_packet": "called (fixes 28, 32)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_pingreq": "called by the inline reader (fix 32)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.wait_disconnect": "wrapped: the first word on how a "
                                                                                "connection ended is kept (fix 32)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.start": "creates the disconnect waiter only after the "
                                                                      "reader runs (why fix 32 keeps the first word)",
    "amqtt.mqtt.protocol.broker_handler:BrokerProtocolHandler.handle_connect": "a second CONNECT: called by the "
                                                                               "inline reader (fix 32)",
    "amqtt.mqtt.protocol.broker_handler:Subscription": "built by the inline reader for _handle_subscription (fix 32)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.stop": "called when the inline reader ends, as amqtt's loop does; "
                                                        "waits for _reader_stopped (fix 32)",
    "amqtt.adapters:StreamReaderAdapter": "_reader, the asyncio stream the inline reader reads (fix 32)",
    "amqtt.mqtt:packet_class": "decodes the inline reader's rare packets (SUBSCRIBE, UNSUBSCRIBE; fix 32)",
    "amqtt.mqtt.packet:MQTTFixedHeader.__init__": "built by the inline reader for amqtt's decoders (fix 32)",
    "amqtt.plugins.manager:PluginManager._load_plugins": "fills _event_plugin_callbacks, which the broker reads to "
                                                         "choose the inline reader (fix 32)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.handle_puback": "wrapped (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.handle_pubrec": "wrapped: a late PUBREC is released (fix 28)",
    "amqtt.mqtt.protocol.handler:ProtocolHandler.handle_pubcomp": "wrapped (fix 28)",
    # -- sessions and messages
    "amqtt.session:Session.__init__": "creates attributes, keep_alive, inflight_out, retained_messages, will_* "
                                      "(all read or set by hardened.py)",
    "amqtt.session:Session._init_states": "replaced by LightSession's (fix 33): connect.py's ConnectionState "
                                          "answers the calls made on its state machine the same way",
    "amqtt.session:Session._on_enter_connected": "called by ConnectionState.connect (fix 33)",
    "amqtt.session:Session._on_enter_disconnected": "called by ConnectionState.disconnect (fix 33)",
    "amqtt.session:Session.next_packet_id": "packet ids skip those still in flight (fix 28 keeps them there)",
    "amqtt.session:ApplicationMessage": "the *_packet slots and build_publish_packet (fix 28)",
    "amqtt.session:OutgoingApplicationMessage": "direction == OUTGOING selects our QoS flows (fix 28)",
    # -- adapters and reading: guard.py and the direct QoS 0 path
    "amqtt.adapters:ReaderAdapter": "PacketGate implements it (fix 14)",
    "amqtt.adapters:WebSocketsReader": "SafeWebSocketsReader overrides _feed_buffer, uses _stream and _protocol "
                                       "(fix 15)",
    "amqtt.adapters:WebSocketsWriter.__init__": "creates _protocol (the transport of a frozen peer is aborted, fix 1)",
    "amqtt.adapters:StreamWriterAdapter": "_writer (the transport fixes 1, 17, 25, 26 use) and is_closed",
    "amqtt.codecs_amqtt:read_or_raise": "the one place amqtt reads from a reader: the gate sees every byte (fix 14)",
    "amqtt.mqtt.packet:MQTTFixedHeader.from_stream": "reads the fixed header through read_or_raise; lets the gate's "
                                                     "exceptions through (fixes 14, 27)",
    # -- plugins: plugins.py and the inline ACL dispatch
    "amqtt.plugins.manager:PluginManager.__init__": "creates _topic_plugins (read by fix 11)",
    "amqtt.plugins.manager:PluginManager._load_str_plugins": "fills _topic_plugins from the config dict (fix 11)",
    "amqtt.plugins.manager:PluginManager._load_str_plugin": "builds each plugin's Config dataclass with dacite "
                                                            "(plugins.py passes the LiveFleet through it)",
    "amqtt.plugins.manager:PluginManager.is_topic_filtering_enabled": "called (fix 11)",
    "amqtt.plugins.manager:PluginManager._map_plugin_method": "the Task per plugin per check fix 11 avoids; stock "
                                                              "auth semantics (fix 4)",
    "amqtt.plugins.manager:PluginManager.map_plugin_topic": "the stock ACL semantics fix 11 keeps",
    "amqtt.plugins.manager:PluginManager.map_plugin_auth": "called through Broker._authenticate (fix 4)",
    "amqtt.plugins.base:BasePlugin.__init__": "sets context and config, which plugins.py reads",
    "amqtt.plugins.base:BaseAuthPlugin": "FleetAuthPlugin overrides authenticate",
    "amqtt.plugins.base:BaseTopicPlugin": "FleetAclPlugin overrides topic_filtering",
}


def installed_version() -> str:
    return importlib.metadata.version("amqtt")


def current_fingerprints(names: Mapping[str, str] = RELIED_ON) -> dict[str, str | None]:
    """name -> sha256 of its source today (None: it cannot be found)."""
    return fingerprints(names)


def load_record() -> dict[str, object]:
    return json.loads(RECORD.read_text(encoding="utf-8"))


def _report(found: list[tuple[str, str]]) -> str:
    return report(found, RELIED_ON)


def test_the_installed_amqtt_is_the_recorded_version() -> None:
    """Every override was written against one amqtt release; the pin, the broker and the record must agree."""
    from roslink_mqtt.broker.hardened import AMQTT_VERSION

    recorded = load_record()["amqtt"]
    installed = installed_version()
    assert installed == recorded, (
        f"amqtt {installed} is installed, but the fixes in roslink_mqtt/broker/hardened.py were checked against "
        f"amqtt {recorded}. Re-diff every internal listed in {Path(__file__).name} (broker/FIXES.md), then run: "
        f"{WRITE}")
    assert AMQTT_VERSION == recorded, f"hardened.AMQTT_VERSION is {AMQTT_VERSION}, the record says {recorded}"
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["optional-dependencies"]
    assert f"amqtt=={recorded}" in extras["broker"], f"pyproject.toml's [broker] extra does not pin amqtt=={recorded}"


def test_every_relied_on_amqtt_source_is_unchanged() -> None:
    recorded = load_record()["sources"]
    assert isinstance(recorded, dict)
    found = differences(recorded, current_fingerprints())
    assert not found, (
        f"amqtt sources the embedded broker relies on differ from the record (amqtt {installed_version()} "
        f"installed):\n{_report(found)}\nRe-diff each against the fix that relies on it, then run: {WRITE}")


def test_an_altered_source_is_reported_by_name() -> None:
    """The check can fail: a real recorded entry whose source gains one line is reported, and only that one."""
    recorded = load_record()["sources"]
    assert isinstance(recorded, dict)
    name = "amqtt.broker:Broker._run_broadcast"
    source = source_of(name)
    assert source is not None and digest(source) == recorded[name]
    current: dict[str, str | None] = dict(recorded)
    current[name] = digest(source + "        self.logger.debug('an upstream edit')\n")
    assert differences(recorded, current) == [(name, CHANGED)]
    current[name] = None  # amqtt removed or moved it
    assert differences(recorded, current) == [(name, GONE)]
    del current[name]  # dropped from RELIED_ON without --write
    assert differences(recorded, current) == [(name, UNLISTED)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.unit.test_amqtt_fingerprint",
                                     description="Check, or record, the amqtt sources the embedded broker relies on.")
    parser.add_argument("--write", action="store_true", help=f"record the installed amqtt's sources in {RECORD.name}")
    args = parser.parse_args(argv)
    current = current_fingerprints()
    if args.write:
        gone = [name for name, value in current.items() if value is None]
        if gone:
            print("not found in the installed amqtt (fix RELIED_ON first):\n  " + "\n  ".join(gone), file=sys.stderr)
            return 1
        record = {"amqtt": installed_version(), "sources": dict(sorted(current.items()))}
        RECORD.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
        print(f"recorded {len(current)} sources of amqtt {record['amqtt']} in {RECORD.relative_to(ROOT)}")
        return 0
    found = differences(load_record()["sources"], current)  # type: ignore[arg-type]
    print(_report(found) if found else f"all {len(current)} recorded amqtt sources unchanged")
    return 1 if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
