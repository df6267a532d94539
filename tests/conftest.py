"""Session-wide test setup.

DDS must stay on this machine: the loopback-only ROS environment and a fresh
ROS_DOMAIN_ID are set before anything imports rclpy, and every subprocess a
test starts inherits them.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest

from roslink_mqtt.ros_env import apply_local_ros_env, unused_domain_ids
from tests.support.measure import MEASUREMENTS

# `pytest -n N` (pytest-xdist) runs N worker processes, each a whole session: each gets a ROS domain of its own.
# The controller imports this file first and picks them all at once (workers inherit its environment), so two
# workers starting together cannot both take the one domain that looked free.
DOMAINS_VAR = "ROSLINK_TEST_DOMAINS"
MAX_WORKERS = 8


def _domain_of_this_process() -> int:
    worker = os.environ.get("PYTEST_XDIST_WORKER")  # "gw0", "gw1", ... in a worker; unset in a plain run
    if worker and os.environ.get(DOMAINS_VAR):
        picked, index = os.environ[DOMAINS_VAR].split(","), 1 + int(worker.removeprefix("gw"))
        if index >= len(picked):
            raise pytest.UsageError(f"at most {MAX_WORKERS} workers (-n): each needs a ROS domain of its own")
        return int(picked[index])
    domains = unused_domain_ids(1 + MAX_WORKERS)
    os.environ[DOMAINS_VAR] = ",".join(map(str, domains))
    return domains[0]


ROS_ENV = apply_local_ros_env(_domain_of_this_process())

# Tests stop the programs they start with Ctrl-C (SIGINT), as a user would. A shell that runs the suite as a
# background job starts it with SIGINT ignored, and an ignored signal stays ignored in every child (Python then
# installs no KeyboardInterrupt handler): take SIGINT back here, so children start with its default again.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Each folder is a kind of test, and its marker: `pytest tests/unit` (or `-m unit`) runs the pure logic in seconds,
# without ROS or a broker (tests/unit/conftest.py refuses an rclpy import there).
FOLDER_MARKERS = ("unit", "integration", "security", "browser")


# Tests kept from the parallel part, marked `alone`: `make test` runs them after the others, two at a time.
# They flood a broker or a robot on purpose and measure that nothing else suffers, or measure freshness through a
# rate-limited link; beside three workers' tests they would measure those (and starve them: a pub's notice came
# after its wait, a bridge missed its broker's answer by 50 ms).
ALONE = ("tests/security/", "tests/integration/test_weak_link.py", "tests/integration/test_presence_flood.py",
         "tests/integration/test_large_slow_viewer.py", "tests/integration/test_rabbitmq_cluster.py",
         "tests/integration/test_wss.py",  # how far 1.5 s of twists move the robot (0.13 m once, beside)
         "tests/integration/test_broker_overload.py")  # floods the broker on purpose

# Two at a time (`pytest -n 2 --dist loadfile -m "alone and not solo"`): a flood beside a flood is to each about
# what `stress-ng --cpu 1` is to the suite, and their lines (round trips) had 5x to spare under that. Alone in the
# machine the `alone` tests took 323 s; now about 280 s. `solo` tests run last, one at a time:
# * the rate-limited links: beside the floods and a CPU hog, the uplink's thread starved and its controller with
#   it (a thin link's rate read 44 kbit/s of 128, poses 2.4 s old after a fall, a service call unanswered);
# * a parameter-read flood's worst twist delay (213 ms beside a hog, against 500 ms reported and 1 s asserted);
# * the RabbitMQ cluster, whose `fleet apply` waits on rabbitmqctl, an Erlang VM per call (a new user drove 2.2 s
#   after the plan beside a hog, 3.0 s beside a hog and the links, against 3 s).
SOLO = ("tests/integration/test_weak_link.py", "tests/security/test_request_flood.py",
        "tests/integration/test_rabbitmq_cluster.py")


def pytest_collection_modifyitems(config, items) -> None:
    tests = Path(__file__).parent
    for item in items:
        where = item.path.relative_to(tests) if item.path.is_relative_to(tests) else None
        if where is None:
            continue
        if where.parts[0] in FOLDER_MARKERS:
            item.add_marker(getattr(pytest.mark, where.parts[0]))
        if f"tests/{where.as_posix()}".startswith(ALONE):
            item.add_marker(pytest.mark.alone)
        if f"tests/{where.as_posix()}".startswith(SOLO):
            item.add_marker(pytest.mark.solo)


def pytest_sessionfinish(session) -> None:
    """A worker of `pytest -n` hands its measurements to the controller, which prints them all."""
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:
        workeroutput["measurements"] = [list(m) for m in MEASUREMENTS]


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: a worker ended
def pytest_testnodedown(node, error) -> None:
    MEASUREMENTS.extend(tuple(m) for m in getattr(node, "workeroutput", {}).get("measurements", []))


# Modules whose tests must run on one worker, one after the other: they share something fixed. (pytest-xdist's own
# xdist_group marker does not group anything under pytest 9: it renames node ids in a way pytest 9 ignores.)
SAME_WORKER = {
    "tests/integration/test_demo.py": "the demo's ports 1883 and 8083",
    "tests/integration/test_docs_run.py": "the demo's ports 1883 and 8083",
}


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: how tests are shared out among the workers
def pytest_xdist_make_scheduler(config, log):
    """`make test` runs `pytest -n 3 --dist loadfile`: a test module goes to one worker whole (its module-scoped
    stack starts once), and the modules of one SAME_WORKER entry go to one worker together."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class ModuleOrShared(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return f"shared: {SAME_WORKER[module]}" if module in SAME_WORKER else module

    return ModuleOrShared(config, log)


def pytest_terminal_summary(terminalreporter) -> None:
    if MEASUREMENTS:
        terminalreporter.section("measured safety timings")
        for name, seconds, deadline in MEASUREMENTS:
            terminalreporter.write_line(f"{name:<48} {seconds * 1000:7.0f} ms   (deadline {deadline * 1000:.0f} ms)")
