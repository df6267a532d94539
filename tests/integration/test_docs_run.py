"""Docs run verbatim: every shell and Python snippet in README.md, docs/*.md, broker/README.md and bridge/README.md.

Each fenced ``sh``/``bash``/``python`` block says what it is in its info string (GitHub shows only the
language):

* ```` ```sh run ```` -- run as written (bash, ``-e``, from the repository root) against a live demo
  fleet: the embedded broker from config/robots.yaml on its default ports 1883/8083, the simulated
  turtle1 and its bridge. It must exit 0 within its time and print no traceback. ``serve=N``: as below,
  its first N commands are servers (the Foxglove gateway), beside the fleet.
* ```` ```sh run fails ```` -- the same, but the example shows an error: it must exit non-zero, still
  without a traceback.
* ```` ```sh run alone ```` -- without the live fleet (the snippet starts what it needs itself).
  ``serve=N``: the first N commands are servers (one terminal each in the docs); they are started in
  the background, the rest runs once they are up, then the servers get SIGINT.
* ```` ```python run ```` -- ``.venv/bin/python`` with the snippet on stdin, against the live fleet;
  ``serve``: a program that runs until stopped must still be running after 3 s, without a traceback, and end
  on Ctrl-C (SIGINT) without one; ``serve rclpy``: a program of plain rclpy (the port of an SDK program), checked
  for a traceback only while it runs, since rclpy's own Ctrl-C can land inside its conversion of a message and end
  in a ``RuntimeError`` no program can catch (once in a clean-clone run beside a CPU hog); ``fragment``: a
  fragment of docs/sdk.md that uses the ``client`` of its *Connecting* example (and a ``driver`` of
  the reader's own): :data:`FRAGMENT_PRELUDE` makes them, and the client is closed after it.
* ```` ```sh norun <reason> ```` -- not run; the reason is required (an interactive terminal, a
  placeholder such as ``<pid>``, root on a real host...).
* ```` ```sh ns <host> [serve=1] ```` -- docs/deploy.md's steps, each on its machine: run by
  tests/integration/test_deploy_guide.py in network namespaces (a server, a robot, a laptop).

Only ``ROS_DOMAIN_ID=<n>`` is rewritten, to this test run's fresh domain (DDS stays on this machine
and apart from other runs); everything else runs exactly as a newcomer would type it.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from roslink_mqtt.localproc import listener_of
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.mqtt_client import TestClient
from tests.support.net import wait_for_port
from tests.support.procs import CONFIG, ROOT, bridge_args, bridge_env, run
from tests.support.waits import never, stays

# The demo fleet's ports are fixed (the docs name them): under `pytest -n` this module and tests/integration/
# test_demo.py run on one worker, one after the other (tests/conftest.py: SAME_WORKER).
pytestmark = pytest.mark.timeout(180)

DOC_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "broker" / "README.md",
             ROOT / "bridge" / "README.md"]
FENCE = re.compile(r"^```([A-Za-z]+)([^\n]*)\n(.*?)^```[ \t]*$", re.M | re.S)
SHELLS = {"sh", "bash", "shell", "console"}
LANGUAGES = SHELLS | {"python"}
STEP_TIMEOUT = 90.0
SERVE_CHECK = 3.0  # s a `serve` program must keep running (a program that fails does so while starting: < 2 s)
DEMO_PORTS = (1883, 8083)
FRAGMENT_PRELUDE = """\
from roslink_mqtt.client import RobotClient
class driver:  # the reader's own hardware driver
    enable = staticmethod(lambda on: print("driver: enable", on))
client = RobotClient("alice", "alice-demo", url="mqtt://127.0.0.1:1883", robots=["turtle1"]).connect()
client.wait_for_robot("turtle1", timeout=10)
"""
FRAGMENT_POSTLUDE = "\nclient.close()\n"


@dataclass(frozen=True)
class Snippet:
    file: Path
    line: int
    language: str
    info: str
    code: str

    @property
    def id(self) -> str:
        return f"{self.file.relative_to(ROOT)}:{self.line}"

    @property
    def words(self) -> list[str]:
        return self.info.split()

    @property
    def runnable(self) -> bool:
        return bool(self.words) and self.words[0] == "run"

    @property
    def alone(self) -> bool:
        return "alone" in self.words

    @property
    def serve(self) -> int:
        for word in self.words:
            if word.startswith("serve="):
                return int(word.split("=", 1)[1])
        return 1 if "serve" in self.words else 0


def snippets() -> list[Snippet]:
    found = []
    for path in DOC_FILES:
        text = path.read_text()
        for match in FENCE.finditer(text):
            language = match.group(1).lower()
            if language in LANGUAGES:
                line = text.count("\n", 0, match.start()) + 1
                found.append(Snippet(path, line, "sh" if language in SHELLS else "python",
                                     match.group(2).strip(), match.group(3)))
    return found


SNIPPETS = snippets()
RUNNABLE = [s for s in SNIPPETS if s.runnable]


def test_every_snippet_is_marked() -> None:
    unmarked = [s.id for s in SNIPPETS if not s.words or s.words[0] not in ("run", "norun", "ns")]
    no_reason = [s.id for s in SNIPPETS if s.words[:1] == ["norun"] and len(s.words) < 2]
    assert not unmarked, f"mark these blocks `run …`, `ns <host>` or `norun <reason>` ({__file__}): {unmarked}"
    assert not no_reason, f"`norun` needs a reason: {no_reason}"
    # `ns <host>` blocks run too, each on its machine (tests/integration/test_deploy_guide.py)
    run_somewhere = [s for s in SNIPPETS if s.runnable or s.words[:1] == ["ns"]]
    assert len(run_somewhere) >= len(SNIPPETS) // 2, "most documentation snippets should run"


# -- the live demo fleet ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def demo_fleet(tmp_path_factory) -> Iterator[None]:
    work = tmp_path_factory.mktemp("docs-fleet")
    for port in DEMO_PORTS:
        if _listening(port):
            pytest.fail(f"port {port} is in use (by {listener_of(port) or 'someone'}): the docs use the demo fleet's "
                        "default ports; stop what listens there")
    broker = EmbeddedBrokerProcess(work, CONFIG)
    broker.port, broker.ws_port = DEMO_PORTS
    with broker, run(["-m", "roslink_mqtt.sim"], work / "sim.log"), \
            run(bridge_args("turtle1", broker.port), work / "bridge.log", bridge_env("turtle1")):
        _wait_online("turtle1", broker.port)
        yield


def _wait_online(robot: str, port: int, timeout: float = 30.0) -> None:
    with TestClient(port, "bob", "bob-demo") as bob:
        assert bob.connect() == 0
        bob.subscribe(f"roslink/{robot}/heartbeat")
        bob.wait_for(lambda m: m.json()["payload"]["system_status"] == 4, timeout=timeout)


def _listening(port: int) -> bool:
    import socket

    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{ROOT / '.venv' / 'bin'}:{env.get('PATH', '')}"
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("ROSLINK_URL", None), env.pop("ROSLINK_USERNAME", None), env.pop("ROSLINK_PASSWORD", None)
    return env


def _localize(code: str) -> str:
    """The one rewrite: the docs' example domain id becomes this run's own."""
    return re.sub(r"ROS_DOMAIN_ID=\d+", f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}", code)


def _commands(code: str) -> list[str]:
    """Shell commands of a block: backslash continuations joined, blank and comment-only lines dropped."""
    joined = re.sub(r"\\\n\s*", " ", code)
    return [line for line in joined.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def _run_shell(script: str, expect_failure: bool) -> str:
    # Output goes to a file, not a pipe: a job the snippet started with '&' would hold a pipe open.
    with tempfile.TemporaryFile() as out_file:
        proc = subprocess.Popen(["bash", "-e", "-o", "pipefail", "-c", script], cwd=ROOT, env=_env(),
                                stdout=out_file, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            proc.wait(timeout=STEP_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        finally:
            try:  # what the snippet started with '&' must not outlive it
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        out_file.seek(0)
        out = out_file.read().decode(errors="replace")
    assert proc.returncode != -signal.SIGKILL, f"still running after {STEP_TIMEOUT:.0f} s:\n{out[-3000:]}"
    if expect_failure:
        assert proc.returncode != 0, f"expected an error, got exit 0:\n{out[-3000:]}"
    else:
        assert proc.returncode == 0, f"exit {proc.returncode}:\n{out[-3000:]}"
    assert "Traceback (most recent call last)" not in out, out[-3000:]
    return out


def _start(command: str, log: Path, *, python: bool = False) -> subprocess.Popen:
    argv = [str(ROOT / ".venv" / "bin" / "python"), "-"] if python else ["bash", "-e", "-c", command]
    with open(log, "wb") as out:
        proc = subprocess.Popen(argv, cwd=ROOT, env=_env(), stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.PIPE if python else subprocess.DEVNULL, start_new_session=True)
    if python:
        assert proc.stdin is not None
        proc.stdin.write(command.encode())
        proc.stdin.close()
    return proc


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(10)
        except (subprocess.TimeoutExpired, ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _run_servers(snippet: Snippet, tmp_path: Path) -> None:
    commands = _commands(_localize(snippet.code))
    env_lines = [c for c in commands if c.startswith("export ")]
    rest = [c for c in commands if not c.startswith("export ")]
    servers, after = rest[: snippet.serve], rest[snippet.serve:]
    prologue = "".join(f"{c}\n" for c in env_lines)
    procs = []
    try:
        for i, command in enumerate(servers):
            proc = _start(prologue + command, tmp_path / f"server{i}.log")
            procs.append(proc)
            if "roslink-mqtt-broker" in command or "roslink_mqtt.broker" in command:
                wait_for_port(DEMO_PORTS[0], timeout=20)
        with_broker = any("roslink-mqtt-broker" in c or "roslink_mqtt.broker" in c for c in servers)
        if with_broker and any("roslink-mqtt-bridge" in c or "roslink_mqtt.bridge" in c for c in servers):
            _wait_online("turtle1", DEMO_PORTS[0])  # sim and bridge are up: the robot's heartbeat says ACTIVE
        else:  # a server that says where it listens (`--port N`, or `# http://127.0.0.1:N/`) is waited for there
            listens = r"--port (\d+)|#\s*https?://127\.0\.0\.1:(\d+)"
            ports = [int(a or b) for c in servers for a, b in re.findall(listens, c)]
            for port in ports:
                wait_for_port(port, timeout=30)
            if not ports:  # one that listens nowhere (a bridge): its exit, if any, shows within 2 s
                try:
                    never("a server exiting", lambda: [i for i, p in enumerate(procs) if p.poll() is not None],
                          seconds=2.0)
                except AssertionError:
                    pass  # which one, with its log: below
        for i, proc in enumerate(procs):
            assert proc.poll() is None, f"{servers[i]!r} exited:\n{(tmp_path / f'server{i}.log').read_text()[-2000:]}"
        if after:
            _run_shell(prologue + "\n".join(after), expect_failure=False)
    finally:
        for proc in reversed(procs):
            _stop(proc)
    for i in range(len(procs)):
        log = (tmp_path / f"server{i}.log").read_text(errors="replace")
        assert "Traceback (most recent call last)" not in log, log[-3000:]


@pytest.mark.parametrize("snippet", [s for s in RUNNABLE if s.alone], ids=lambda s: s.id)
def test_alone(snippet: Snippet, tmp_path: Path) -> None:
    for port in DEMO_PORTS:
        assert not _listening(port), f"port {port} busy (by {listener_of(port) or 'someone'}): a snippet that runs " \
            "alone needs it"
    if snippet.serve:
        _run_servers(snippet, tmp_path)
    else:
        _run_shell(_localize(snippet.code), expect_failure="fails" in snippet.words)


@pytest.mark.parametrize("snippet", [s for s in RUNNABLE if not s.alone], ids=lambda s: s.id)
def test_with_demo_fleet(snippet: Snippet, demo_fleet, tmp_path: Path) -> None:
    if snippet.language == "python":
        if snippet.serve:
            proc = _start(snippet.code, tmp_path / "program.log", python=True)
            try:
                stays("the program running", lambda: proc.poll() is None, seconds=SERVE_CHECK)
            except AssertionError:
                pass  # said below with its log, once it is stopped
            alive = proc.poll() is None
            running = (tmp_path / "program.log").read_text(errors="replace")  # what it wrote before the Ctrl-C
            _stop(proc)
            log = (tmp_path / "program.log").read_text(errors="replace")
            assert alive, f"the program ended early:\n{log[-3000:]}"
            assert "Traceback (most recent call last)" not in (running if "rclpy" in snippet.words else log), \
                log[-3000:]
            return
        code = FRAGMENT_PRELUDE + snippet.code + FRAGMENT_POSTLUDE if "fragment" in snippet.words else snippet.code
        done = subprocess.run([str(ROOT / ".venv" / "bin" / "python"), "-"], input=code, cwd=ROOT,
                              env=_env(), capture_output=True, text=True, timeout=STEP_TIMEOUT)
        out = done.stdout + done.stderr
        assert done.returncode == 0, out[-3000:]
        assert "Traceback (most recent call last)" not in out, out[-3000:]
        return
    if snippet.serve:  # a program of the reader's (docs/foxglove.md's gateway) beside the live fleet
        _run_servers(snippet, tmp_path)
        return
    _run_shell(_localize(snippet.code), expect_failure="fails" in snippet.words)


def test_snippet_parser_sees_every_fence() -> None:
    """A fence the regex missed would silently escape the check: count fences the simple way too."""
    for path in DOC_FILES:
        opened = [m for m in re.finditer(r"^```([A-Za-z]*)", path.read_text(), re.M) if m.group(1).lower() in LANGUAGES]
        assert len(opened) == sum(1 for s in SNIPPETS if s.file == path), path
