"""``make demo``: show the working parts on this machine.

Grows with the project; each stage prints what it proves.
"""

from __future__ import annotations

import sys

from .cli.fleet_cmd import summary
from .config import load_fleet
from .protocol import MessageId, ProtocolError, decode, encode_message


def main(config: str = "config/robots.yaml") -> int:
    fleet = load_fleet(config)
    print(summary(fleet))
    topic = fleet.topics.command("turtle1", "alice", "twist")
    wire = encode_message(MessageId.TWIST, {"lx": 0.2, "az": 0.5}, system_id=1, sequence_number=17)
    print(f"\nalice → {topic}\n  {wire.decode()}")
    print(f"  decoded: {decode(wire, MessageId.TWIST)}")
    for bad in (b'{"lx": "fast"}', b'{"lx": 1e999}', b'{"lxx": 0.1}', b"not json"):
        try:
            decode(bad, MessageId.TWIST)
        except ProtocolError as err:
            print(f"  refused {bad.decode()!r}: {err}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
