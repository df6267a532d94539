"""A plain ROS 2 node (rclpy) calling the services that ``legacy_service.py`` provides over MQTT.

    .venv/bin/python examples/ros_caller.py [--timeout 20]

Run it in the robot's ROS environment (same ROS_DOMAIN_ID and discovery
settings as the bridge). Nothing here knows about MQTT: the services look like
any other ROS services. Exits 0 when every call succeeded.
"""

from __future__ import annotations

import argparse
import sys

import rclpy
from std_srvs.srv import SetBool, Trigger


def call(node, client, request, timeout: float):
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if not future.done():
        client.remove_pending_request(future)
        raise TimeoutError(f"{client.srv_name}: no answer within {timeout:g} s")
    return future.result()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for each service (%(default)s)")
    args = p.parse_args(argv)

    rclpy.init()
    node = rclpy.create_node("ros_caller")
    enable = node.create_client(SetBool, "enable_motors")
    self_test = node.create_client(Trigger, "self_test")
    ok = True
    try:
        for client in (enable, self_test):
            if not client.wait_for_service(timeout_sec=args.timeout):
                print(f"{client.srv_name} did not appear within {args.timeout:g} s", file=sys.stderr)
                return 1
        for name, client, request in (("enable_motors(true)", enable, SetBool.Request(data=True)),
                                      ("self_test", self_test, Trigger.Request()),
                                      ("enable_motors(false)", enable, SetBool.Request(data=False))):
            response = call(node, client, request, args.timeout)
            print(f"{name}: success={response.success} message={response.message!r}", flush=True)
            ok = ok and response.success
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
