"""The paho-mqtt internals the bridge and the SDK reach into are the ones they were written against.

pyproject.toml pins paho-mqtt to a minor release (2.2), and the tests that use these internals run against real
brokers; but a patch release may still change a private method without breaking an import, and the uplink would
then misjudge its queue, or failover connect to the dead node, silently. So, as for amqtt
(tests/unit/test_amqtt_fingerprint.py; both use tests/support/fingerprint.py), the source of each internal we
rely on is hashed and compared with ``paho_fingerprint.json``. After re-reading every reported name against its
user below, record the new sources: ``python -m tests.unit.test_paho_fingerprint --write``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
from pathlib import Path

import pytest

from tests.support.fingerprint import differences, digest, source_of
from tests.support.fingerprint import fingerprints as current_fingerprints

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[2]
RECORD = Path(__file__).with_name("paho_fingerprint.json")
WRITE = "python -m tests.unit.test_paho_fingerprint --write"

# ``module:qualified.name`` -> who relies on it, and on what
RELIED_ON: dict[str, str] = {
    "paho.mqtt.client:Client.__init__": "creates _out_packet (a deque of dicts with to_process: uplink_sender."
                                        "paho_unsent), _host, _port and _client_id (mqtt.Failover.advance)",
    "paho.mqtt.client:Client._packet_queue": "appends each outgoing packet to _out_packet with its to_process; "
                                             "wrapped per paced lane (bridge/pacer.zero_copy_queue): a large "
                                             "packet is queued as a memoryview",
    "paho.mqtt.client:Client._packet_write": "writes _out_packet's head, lowers to_process, pops what is written: "
                                             "what is left is what paho holds unsent; slices packet[pos:] at "
                                             "every attempt (a copy, unless the packet is a view: "
                                             "bridge/core/pacer.py)",
    "paho.mqtt.client:Client._send_pingreq": "MqttLink.ping: the path meter's probe (bridge/core/path_meter.py); "
                                             "wrapped so the keep-alive's PINGREQs enter bridge/core/ping_ledger.py "
                                             "too; sets "
                                             "_ping_t after queuing (MqttLink clears it when the answer came first)",
    "paho.mqtt.client:Client._handle_pingresp": "wrapped by MqttLink: a PINGRESP answers the oldest PINGREQ (the "
                                                "ledger says if a probe's); sets _ping_t to 0",
    "paho.mqtt.client:Client._sock_send": "wrapped per paced lane (bridge/core/pacer.py): writes part of a buffer or "
                                          "raises "
                                          "BlockingIOError, as a full socket would; only _packet_write calls it",
    "paho.mqtt.client:Client.loop_misc": "drops the connection when _ping_t stays set for keepalive s: why a mark "
                                         "left set after its answer must be cleared",
    "paho.mqtt.client:Client._check_keepalive": "drops a connection that received nothing (_last_bytes_received, "
                                                "under _msgtime_mutex, time_func monotonic) for keepalive s after "
                                                "its PINGREQ: MqttLink.heard_while_writing moves that clock while a "
                                                "paced lane's message leaves",
    "paho.mqtt.client:Client.reconnect": "connects to _host/_port with _client_id, which failover sets before it",
    "paho.mqtt.client:Client._messages_reconnect_reset_out": "a QoS 1 message still waiting for its PUBACK is sent "
                                                             "again on reconnect (a heartbeat may arrive twice: "
                                                             "tests/integration/test_failsafe_faults.py)",
}


def installed_version() -> str:
    return importlib.metadata.version("paho-mqtt")


def test_the_installed_paho_is_the_recorded_version() -> None:
    recorded = json.loads(RECORD.read_text(encoding="utf-8"))["paho-mqtt"]
    assert installed_version() == recorded, (
        f"paho-mqtt {installed_version()} is installed; the internals below were checked against {recorded}: "
        f"re-read each, then run {WRITE}")


def test_every_relied_on_paho_source_is_unchanged() -> None:
    recorded = json.loads(RECORD.read_text(encoding="utf-8"))["sources"]
    found = differences(recorded, current_fingerprints(RELIED_ON))
    assert not found, ("paho-mqtt sources we rely on differ from the record:\n"
                       + "\n".join(f"  {what}: {name} -- {RELIED_ON.get(name, '')}" for name, what in found)
                       + f"\nRe-read each against its user, then run: {WRITE}")


def test_a_changed_paho_source_is_reported() -> None:
    """The check can fail: one recorded source with a line more is reported by name."""
    recorded = json.loads(RECORD.read_text(encoding="utf-8"))["sources"]
    name = "paho.mqtt.client:Client._send_pingreq"
    source = source_of(name)
    assert source is not None
    current: dict[str, str | None] = dict(recorded)
    current[name] = digest(source + "        pass\n")
    assert differences(recorded, current) == [(name, "changed")]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.unit.test_paho_fingerprint")
    parser.add_argument("--write", action="store_true", help=f"record the installed paho's sources in {RECORD.name}")
    args = parser.parse_args(argv)
    current = current_fingerprints(RELIED_ON)
    gone = [name for name, value in current.items() if value is None]
    if gone:
        print("not found in the installed paho-mqtt:\n  " + "\n  ".join(gone), file=sys.stderr)
        return 1
    if args.write:
        record = {"paho-mqtt": installed_version(), "sources": dict(sorted(current.items()))}
        RECORD.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
        print(f"recorded {len(current)} sources of paho-mqtt {record['paho-mqtt']} in {RECORD.relative_to(ROOT)}")
        return 0
    found = differences(json.loads(RECORD.read_text(encoding="utf-8"))["sources"], current)
    for name, what in found:
        print(f"{what}: {name}")
    return 1 if found else 0


if __name__ == "__main__":
    raise SystemExit(main())
