"""A viewer floods the requests viewers may make (parameter reads, read-only service calls).

bob is a viewer of turtle1: the ACL lets him publish ``from/bob/param/<node>`` (reads are open to viewers)
and ``from/bob/call/<read-only service>``. Each request becomes a ROS service call on the robot, so an
unbounded stream of them would queue work on the robot without limit. While bob floods as fast as one
client can publish, alice drives at 20 Hz: her commands must keep reaching ``/cmd_vel`` promptly, the robot
must stay online (its link to the broker up), and the requests that reach ROS stay bounded: through Mosquitto
bob is told why requests beyond his bound are refused; the embedded broker paces his login before that.
Real processes: a broker (embedded and exported Mosquitto), the simulated robot and its bridge.
"""

from __future__ import annotations

import subprocess
import sys
import time
from contextlib import ExitStack

import orjson
import pytest

from tests.support.broker_setup import write_fleet
from tests.support.marked_twists import MarkedTwists, nonzero
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import ROOT
from tests.support.robot_stack import BROKERS
from tests.support.ros import RosProbe
from tests.support.stack import live_robot
from tests.support.waits import stays

pytestmark = [pytest.mark.security, pytest.mark.timeout(120)]

FLOOD_SECONDS, FLOOD_MAX = 3.0, 60_000  # bounded in time and count
DELAY_BOUND = 0.5  # s: generous; idle p99 is a few ms
TWIST = "roslink/turtle1/from/alice/cmd/twist"
PARAM = "roslink/turtle1/from/bob/param/sim_robot"


@pytest.mark.parametrize("broker", BROKERS)
def test_a_viewer_flooding_parameter_reads_neither_delays_commands_nor_queues_work_on_the_robot(tmp_path,
                                                                                                 broker) -> None:
    from geometry_msgs.msg import Twist

    probe = RosProbe()
    with ExitStack() as exits:
        exits.callback(probe.close)
        cmd_vel = probe.watch(Twist, "/cmd_vel", 2000)
        # the per-user bound at 1 (default 16): through Mosquitto the bridge then has more than its bound in flight
        # even when the flood reaches it slowly (a busy machine: one bridge thread reading, one answering, one GIL,
        # and a run once kept 16 from ever being in flight: answered 1,854 of 60,000, none refused)
        fleet = write_fleet(tmp_path, read_only_service=False, edit=lambda text: text.replace(
            "      command_timeout: 1.0\n", "      command_timeout: 1.0\n      max_requests_per_user: 1\n", 1))
        port = exits.enter_context(live_robot(tmp_path, broker, fleet=fleet)).port
        alice = exits.enter_context(TestClient(port, "alice", "alice-demo", operator=True))
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/state/ack")
        alice.subscribe("roslink/turtle1/heartbeat")
        bob = exits.enter_context(TestClient(port, "bob", "bob-demo", client_id="bob-reads"))
        assert bob.connect() == 0
        bob.subscribe("roslink/turtle1/to/bob/#")  # every program of bob's reads his replies and errors
        time.sleep(0.3)

        twists = MarkedTwists(alice, TWIST, lx=0.1, period=0.05).start()
        exits.callback(twists.stop)
        cmd_vel.wait_for(nonzero, timeout=20)

        flood_start = time.monotonic()
        flood = subprocess.run([sys.executable, "-m", "tests.support.flood_proc", str(port), "bob", "bob-demo", PARAM,
                                "--seconds", str(FLOOD_SECONDS), "--max", str(FLOOD_MAX)],
                               capture_output=True, text=True, timeout=FLOOD_SECONDS + 30, cwd=ROOT)
        flood_end = time.monotonic()
        assert flood.returncode == 0, flood.stderr[-2000:]
        n = orjson.loads(flood.stdout.strip().splitlines()[-1])["sent"]
        # twists sent during the flood may land up to command_timeout (1 s) later; her stream goes on meanwhile
        # (a window, judged by the delays below: a stall that catches up is theirs to measure)
        stays("alice's twist stream running", twists._thread.is_alive, seconds=1.0)
        twists.stop()
        delays = twists.delays(cmd_vel.since(flood_start), flood_start, flood_end)
        worst, p50, p99 = delays.worst, delays.quantile(0.5), delays.quantile(0.99)
        got = bob.drain(3.0)
        window = time.monotonic() - flood_start  # bob's requests can reach the bridge until here
        replies = [m for m in got if "/param_reply/" in m.topic]
        errors = [m.json() for m in got if m.topic.endswith("/error")]
        busy = [e for e in errors if "in flight" in e.get("error", "")]
        other = {e.get("error") for e in errors if e not in busy}
        acks = [m.json()["payload"]["text"] for m in alice.drain(0.2) if m.topic.endswith("/state/ack")]
        offline = [m for m in alice.drain(0.0) if m.topic.endswith("/heartbeat")
                   and m.json()["payload"]["system_status"] != 4]
        report = (f"[{broker}] bob sent {n} parameter reads in {flood_end - flood_start:.1f} s (until written); "
                  f"answered {len(replies)}, refused as too many in flight {len(busy)} (other errors "
                  f"{len(errors) - len(busy)}: {sorted(other)[:3]}); alice: {len(delays.delivered)}/{delays.sent} "
                  f"twists during the flood, p50 {p50 * 1000:.0f} ms, p99 {p99 * 1000:.0f} ms, "
                  f"worst {worst * 1000:.0f} ms; acks {acks}")
        print(report, file=sys.stderr)
        record_measurement(f"[{broker}] parameter-read flood: worst twist delay", worst, DELAY_BOUND)

        assert not [t for t in acks if "lost the broker" in t], report  # the robot's link stayed up
        assert not offline, report
        assert len(delays.delivered) >= 0.9 * delays.sent, report
        # reported against DELAY_BOUND above; asserted at command_timeout (1 s: a twist later than that is dropped
        # by the bridge, the failure this defends against). 33 twists make the p99 the second worst, and a loaded
        # clean-clone run measured p99 536 / worst 587 ms with the defence working (issue 47)
        assert p99 <= 1.0 and worst <= 1.0, report
        if broker == "mosquitto":  # nothing paces bob there: the bridge's per-user bound refuses, with the reason
            assert busy, report  # told why, not silently dropped
            assert "max_requests_per_user" in busy[0]["error"], busy[0]
        else:  # the embedded broker paces bob's login (user_publish_rate 100/s after a burst of 200)
            reached = len(replies) + len(busy)
            assert reached <= 1.5 * (200 + 100 * window), f"{reached} requests reached the bridge in {window:.1f} s"
