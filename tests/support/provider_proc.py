"""A program without ROS that provides services through the bridge (plain paho), run as a process.

    python -m tests.support.provider_proc PORT USER PASSWORD ROBOT

Provides, all std_srvs/srv/Trigger: ``self_test`` (answers success at once), ``hang``
(never answers, so tests can kill it mid-call), ``later`` (answers each call 0.5 s
after it arrived, from a timer thread, so calls overlap) and ``mute`` (never answers,
offered with a 1 s timeout).
"""

from __future__ import annotations

import sys
import threading
import time

import orjson

from roslink_mqtt.client.presence import OperatorPresence
from roslink_mqtt.mqtt import make_client
from roslink_mqtt.topics import TopicTree


def main() -> None:
    port, user, password, robot = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
    topics = TopicTree()
    client_id = f"provider-{user}-{time.monotonic_ns()}"
    client = make_client(client_id, username=user, password=password, url=f"mqtt://127.0.0.1:{port}")
    presence = OperatorPresence(client, user, client_id)

    def on_message(_c, _u, msg) -> None:
        name = msg.topic.rsplit("/", 1)[1]
        request = orjson.loads(msg.payload)
        def answer(message: str) -> None:
            client.publish(topics.response(robot, user, name), orjson.dumps(
                {"id": request["id"], "result": True, "values": {"success": True, "message": message}}), qos=1)

        if name == "self_test":
            answer("all good")
        elif name == "later":
            threading.Timer(0.5, answer, args=(f"answered {request['id']}",)).start()

    def on_connect(c, _u, _f, rc, _p) -> None:
        c.subscribe(f"{topics.prefix}/{robot}/to/{user}/request/+", qos=1)
        for name, timeout in (("self_test", 20), ("hang", 20), ("later", 20), ("mute", 1)):
            offer = orjson.dumps({"type": "std_srvs/srv/Trigger", "timeout": timeout, "client_id": client_id})
            c.publish(topics.provide(robot, user, name), offer, qos=1, retain=True)
        presence.beat()

    client.on_message, client.on_connect = on_message, on_connect
    client.connect("127.0.0.1", port, keepalive=2)
    presence.start()
    print("provider ready", flush=True)
    client.loop_forever()


if __name__ == "__main__":
    main()
