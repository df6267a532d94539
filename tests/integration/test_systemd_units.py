"""The systemd units start on a stock Debian/Ubuntu host (issue 13 item 3).

What runs here, in a container without systemd as PID 1:

* ``systemd-analyze verify`` on both units, in a mount namespace where /opt/roslink-mqtt/.venv exists (so
  the ExecStart binaries are checked for real) — syntax, keys, specifiers, dependencies.
* The bridge unit's ExecStart, expanded as systemd does (``${VAR}`` one word, ``$VAR`` split), with the
  environment systemd would give it (PATH, USER, HOME from the user's passwd entry, Environment= with its
  specifiers, then EnvironmentFile=; nothing inherited from pytest), in an approximation of the unit's sandbox:
  a private mount namespace where everything is read-only except /dev, /proc, /sys, the StateDirectory= and
  LogsDirectory= (ProtectSystem=strict), /home, /root and /run/user are empty and inaccessible
  (ProtectHome=true), /tmp and /var/tmp are private (PrivateTmp=true), and the process runs as an unprivileged
  user with no_new_privs (User=, NoNewPrivileges=). The files install.sh creates (/etc/roslink-mqtt/…,
  /opt/roslink-mqtt/.venv) are overlaid onto /etc and /opt; the venv is one made by the system Python whose
  site-packages are the project's. The bridge must report READY and "connected" over the notify socket to a
  real Mosquitto; the unit as it was before the fix must fail as the issue says.
* The broker unit's ExecStart in the same sandbox (listening is enough).
* ``deploy/install.sh --dry-run``: the user, venv, configuration and unit paths it would create are the
  ones the units name.

What it cannot check: systemd itself (no PID 1 here) — cgroups, the journal, Restart=/WatchdogSec= handling,
the exact mount flags systemd uses, whether LOCALHOST discovery finds SUBNET nodes (no network may see DDS
here), and useradd/pip on a real host: install.sh was run by hand as root in a namespace with overlays on
/etc, /opt and /var (45-50 s the first time from the local package index, 10 s again; the installed units
pass systemd-analyze verify, the installed entry points run as their users); that is not part of this test.
Running as nobody leaves LTTng's usual /dev/shm/lttng-ust-wait-6-65534 (4 KB) behind.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from tests.support.fleet_brokers import mosquitto_with_logins
from tests.support.mqtt_client import TestClient
from tests.support.net import free_port, wait_for_port
from tests.support.procs import CONFIG, DEMO_PASSWORDS, ROOT

pytestmark = [
    pytest.mark.timeout(90),
    pytest.mark.skipif(os.geteuid() != 0, reason="needs root for mount namespaces and changing user"),
    pytest.mark.skipif(not all(shutil.which(tool) for tool in ("unshare", "setpriv", "mount")),
                       reason="needs util-linux unshare, setpriv and mount"),
]

BRIDGE_UNIT = ROOT / "bridge" / "roslink-mqtt-bridge.service"
BROKER_UNIT = ROOT / "broker" / "roslink-mqtt-broker.service"
BRIDGE_ENV = ROOT / "bridge" / "roslink-mqtt-bridge.env"
INSTALL = ROOT / "deploy" / "install.sh"
PREFIX = "/opt/roslink-mqtt"
SYSTEMD_ANALYZE = shutil.which("systemd-analyze") or "/usr/bin/systemd-analyze"
# HOME as the passwd entry gives it: install.sh creates roslink with --home-dir /nonexistent; before the fix
# the unit named a `robot` user, whose home useradd puts at /home/robot.
PASSWD_HOME = {"roslink": "/nonexistent", "robot": "/home/robot"}
RUN_AS = 65534  # nobody:nogroup stands in for roslink:roslink
SPECIFIERS = {"%S": "/var/lib", "%L": "/var/log", "%t": "/run", "%C": "/var/cache", "%%": "%"}
# The variables that keep DDS on this machine (set by tests/conftest.py): passed to every ROS child.
LOCAL_DDS = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE", "RMW_IMPLEMENTATION", "ROS_DOMAIN_ID")

# The bridge unit before the fix (commit 3a8452f), [Service] as shipped (ExecStart wrapped here).
OLD_BRIDGE_UNIT = """\
[Service]
Type=notify
WatchdogSec=5
NotifyAccess=main
User=robot
EnvironmentFile=/etc/roslink-mqtt/bridge.env
ExecStart=/opt/roslink-mqtt/.venv/bin/roslink-mqtt-bridge --config /etc/roslink-mqtt/robots.yaml \\
    --robot ${ROSLINK_ROBOT} $ROSLINK_BRIDGE_ARGS
ExecReload=/bin/kill -HUP $MAINPID
Restart=always
RestartSec=1
KillSignal=SIGTERM
TimeoutStopSec=5
NoNewPrivileges=true
ProtectSystem=strict
ProtectHome=true
PrivateTmp=true
"""

STASH = "/opt/.roslink-test-checkout"  # inside the /opt overlay: outside every tree the sandbox hides

# Runs as root inside `unshare -m`: approximates the unit's sandbox, then becomes the unit's user.
SANDBOX = r"""
set -euo pipefail
fake=$1 uid=$2 workdir=$3 writable=$4 keep=$5 repo=$6
shift 6
# What install.sh creates, overlaid read-only onto the real tree.
for top in etc opt var/lib var/log; do
    if [ -d "$fake/$top" ]; then mount -t overlay overlay -o "lowerdir=$fake/$top:/$top" "/$top"; fi
done
# The checkout under test (the stand-in venv's packages live in it) may sit where the sandbox hides things
# (a CI clone under /tmp, say): set it aside now, show it again read-only at its own path below.
case $repo in
    /tmp/*|/var/tmp/*|/root/*|/home/*|/run/user/*) mount --bind "$repo" "$STASH" ;;
    *) repo="" ;;
esac
# An interpreter that lives under /root (fallback only, see fake_venv) stays reachable, read-only.
if [ -n "$keep" ]; then mount --bind "$keep" "$fake/keep"; fi
# ProtectSystem=strict: everything read-only but the API file systems.
mapfile -t mounts < <(awk '{print $5}' /proc/self/mountinfo)
for mp in "${mounts[@]}"; do
    case $mp in /proc|/proc/*|/sys|/sys/*|/dev|/dev/*) continue ;; esac
    mount -o remount,bind,ro "$mp" 2>/dev/null || echo "sandbox: could not make $mp read-only" >&2
done
# StateDirectory=, LogsDirectory=: writable for the user.
for pair in $writable; do
    mount --bind "${pair%%:*}" "${pair#*:}"
    mount -o remount,bind,rw "${pair#*:}"
done
# ProtectHome=true
for dir in /home /root /run/user; do
    if [ -d "$dir" ]; then mount -t tmpfs -o mode=000,ro tmpfs "$dir"; fi
done
if [ -n "$keep" ]; then
    mount -t tmpfs -o mode=0711 tmpfs /root
    mkdir -p "$keep"
    mount --bind "$fake/keep" "$keep"
    mount -o remount,bind,ro "$keep"
fi
# PrivateTmp=true
mount -t tmpfs -o mode=1777 tmpfs /tmp
mount -t tmpfs -o mode=1777 tmpfs /var/tmp
if [ -n "$repo" ]; then
    top=/$(echo "$repo" | cut -d/ -f2)
    [ "$top" = /var ] && top=/var/tmp
    [ "$top" = /run ] && top=/run/user
    if ! mkdir -p "$repo" 2>/dev/null; then  # a closed home: an empty, unlistable one in its place
        mount -t tmpfs -o mode=0711 tmpfs "$top"
        mkdir -p "$repo"
    fi
    mount --bind "$STASH" "$repo"
    mount -o remount,bind,ro "$repo"
fi
if touch /usr/.sandbox-probe 2>/dev/null; then echo "sandbox: /usr is writable" >&2; exit 97; fi
cd "$workdir"
if [ "$uid" = 0 ]; then exec "$@"; fi
exec setpriv --reuid="$uid" --regid="$uid" --groups="$uid" --no-new-privs -- "$@"
"""


# -- reading units as systemd does --------------------------------------------------------------------------------


def service_section(text: str) -> list[tuple[str, str]]:
    """(key, value) pairs of [Service], in order, continuation lines joined."""
    pairs, section = [], None
    for line in re.sub(r"\\\n", " ", text).splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        if line.startswith("["):
            section = line
        elif section == "[Service]":
            key, _, value = line.partition("=")
            pairs.append((key.strip(), value.strip()))
    return pairs


def values(pairs: list[tuple[str, str]], key: str) -> list[str]:
    return [v for k, v in pairs if k == key]


def one(pairs: list[tuple[str, str]], key: str, default: str | None = None) -> str:
    found = values(pairs, key)
    if not found:
        assert default is not None, f"the unit has no {key}="
        return default
    return found[-1]


def specifiers(value: str) -> str:
    def replace(m: re.Match) -> str:
        assert m.group(0) in SPECIFIERS, f"specifier {m.group(0)} not modelled by this test"
        return SPECIFIERS[m.group(0)]

    return re.sub(r"%.", replace, value)


def environment_file(path: Path) -> dict[str, str]:
    env = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        key, _, value = line.partition("=")
        value = value.strip()
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
            value = value[1:-1]
        env[key.strip()] = value
    return env


def service_env(pairs: list[tuple[str, str]], fake: Path, extra: dict[str, str]) -> dict[str, str]:
    """The environment systemd starts ExecStart with (nothing inherited), then ``extra``."""
    user = one(pairs, "User")
    env = {"PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin", "LANG": "C.UTF-8", "USER": user,
           "LOGNAME": user, "HOME": PASSWD_HOME[user], "SHELL": "/usr/sbin/nologin"}
    for key, var in (("StateDirectory", "STATE_DIRECTORY"), ("LogsDirectory", "LOGS_DIRECTORY")):
        if values(pairs, key):
            base = {"StateDirectory": "/var/lib", "LogsDirectory": "/var/log"}[key]
            env[var] = f"{base}/{one(pairs, key)}"
    for assignments in values(pairs, "Environment"):  # Environment= first, EnvironmentFile= overrides it
        for word in shlex.split(specifiers(assignments)):
            key, _, value = word.partition("=")
            env[key] = value
    for file in values(pairs, "EnvironmentFile"):
        env.update(environment_file(fake / file.lstrip("-").lstrip("/")))
    if values(pairs, "WatchdogSec"):
        env["WATCHDOG_USEC"] = str(int(float(one(pairs, "WatchdogSec")) * 1_000_000))
    env.update(extra)
    for key in LOCAL_DDS:  # whatever the unit says: DDS stays on this machine, in this run's domain
        env[key] = os.environ[key]
    return env


def exec_start(pairs: list[tuple[str, str]], env: dict[str, str]) -> list[str]:
    """ExecStart's argv: ``${VAR}`` is one word, a word ``$VAR`` splits at whitespace (systemd.service(5))."""
    argv = []
    for word in shlex.split(one(pairs, "ExecStart")):
        whole = re.fullmatch(r"\$([A-Za-z_][A-Za-z0-9_]*)", word)
        if whole:
            argv += env.get(whole.group(1), "").split()
        else:
            argv.append(re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", lambda m: env.get(m.group(1), ""), word))
    return argv


# -- what install.sh creates, as a tree to overlay -----------------------------------------------------------------


def fake_venv(venv: Path) -> Path | None:
    """PREFIX/.venv: a venv of the system Python whose lib/ (site-packages, ROS libraries) is the project's.

    Returns a directory the sandbox must keep reachable under /root when there is no system Python 3.11 and
    the project's own venv (whose interpreter may live under /root) has to stand in.
    """
    project = ROOT / ".venv"
    system = Path("/usr/bin/python3.11")
    if not system.exists():
        venv.symlink_to(project)
        base = Path(sys.base_prefix).resolve()
        return base if str(base).startswith(("/root/", "/home/")) else None
    subprocess.run([str(system), "-m", "venv", "--without-pip", str(venv)], check=True)
    shutil.rmtree(venv / "lib")
    (venv / "lib").mkdir()
    for entry in (project / "lib").iterdir():
        if entry.name != "python3.11":
            (venv / "lib" / entry.name).symlink_to(entry)
    (venv / "lib" / "python3.11").mkdir()
    (venv / "lib" / "python3.11" / "site-packages").symlink_to(project / "lib" / "python3.11" / "site-packages")
    (venv / "share").symlink_to(project / "share")  # the ROS wheels' share/ (.msg files: the snapshot's schemas)
    for name, module in (("roslink-mqtt-bridge", "roslink_mqtt.bridge.main"),
                         ("roslink-mqtt-broker", "roslink_mqtt.broker.main")):
        script = venv / "bin" / name  # what pip writes, shebang at the installed path
        script.write_text(f"#!{PREFIX}/.venv/bin/python\nimport sys\nfrom {module} import main\n"
                          f"if __name__ == '__main__':\n    sys.exit(main())\n")
        script.chmod(0o755)
    return None


def fake_root(tmp_path: Path, broker_port: int) -> tuple[Path, Path | None]:
    """/etc/roslink-mqtt and /opt/roslink-mqtt as install.sh leaves them (robots.yaml: demo fleet)."""
    fake = tmp_path / "root"
    etc = fake / "etc" / "roslink-mqtt"
    etc.mkdir(parents=True)
    os.chown(etc, 0, RUN_AS)
    etc.chmod(0o750)
    fleet = CONFIG.read_text()
    fleet, n = re.subn(r"(?m)^(broker:\n(?:  .*\n)*?  port: )1883$", rf"\g<1>{broker_port}", fleet)
    assert n == 1, "config/robots.yaml: broker.port not found"
    fleet = re.sub(r"(?m)^  ws_port: 8083$", "  ws_port: 0", fleet)
    (etc / "robots.yaml").write_text(fleet)
    os.chown(etc / "robots.yaml", 0, RUN_AS)
    (etc / "robots.yaml").chmod(0o640)
    shutil.copy(BRIDGE_ENV, etc / "bridge.env")
    (etc / "bridge.env").chmod(0o600)
    (fake / "opt" / "roslink-mqtt").mkdir(parents=True)
    (fake / STASH.lstrip("/")).mkdir(parents=True)  # where the sandbox sets the checkout aside
    keep = fake_venv(fake / "opt" / "roslink-mqtt" / ".venv")
    (fake / "keep").mkdir()
    for unit_dir in ("var/lib/roslink-mqtt-bridge", "var/log/roslink-mqtt-bridge"):
        (fake / unit_dir).mkdir(parents=True)
    return fake, keep


def writable_dir(path: Path) -> Path:
    path.mkdir()
    os.chown(path, RUN_AS, RUN_AS)
    return path


def sandboxed(fake: Path, keep: Path | None, argv: list[str], *, uid: int = RUN_AS, workdir: str = "/",
              writable: dict[Path, str] | None = None) -> list[str]:
    pairs = " ".join(f"{src}:{dst}" for src, dst in (writable or {}).items())
    script = SANDBOX.replace("$STASH", STASH)
    return ["unshare", "-m", "--propagation", "private", "bash", "-c", script, "sandbox",
            str(fake), str(uid), workdir, pairs, str(keep or ""), str(ROOT), *argv]


# -- the tests ------------------------------------------------------------------------------------------------------


def test_units_pass_systemd_analyze_verify(tmp_path) -> None:
    assert Path(SYSTEMD_ANALYZE).exists(), "systemd-analyze (package systemd) is needed"
    fake, keep = fake_root(tmp_path, free_port())
    done = subprocess.run(sandboxed(fake, keep, [SYSTEMD_ANALYZE, "verify", str(BRIDGE_UNIT), str(BROKER_UNIT)],
                                    uid=0),
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 0 and not done.stderr.strip() and not done.stdout.strip(), done.stdout + done.stderr

    # The check is real: the same verify without the venv install.sh creates fails on ExecStart.
    (fake / "opt" / "roslink-mqtt" / ".venv").rename(fake / "opt" / "roslink-mqtt" / "not-the-venv")
    done = subprocess.run(sandboxed(fake, keep, [SYSTEMD_ANALYZE, "verify", str(BRIDGE_UNIT)], uid=0),
                          capture_output=True, text=True, timeout=30)
    assert done.returncode != 0 and "roslink-mqtt-bridge is not executable" in done.stderr, done.stderr


def test_sandbox_is_what_the_unit_asks_for(tmp_path) -> None:
    """The approximation itself: only the unit's directories and the private /tmp are writable."""
    fake, keep = fake_root(tmp_path, free_port())
    state, logs = writable_dir(tmp_path / "state"), writable_dir(tmp_path / "logs")
    probe = ("for p in /usr /etc /etc/roslink-mqtt /opt/roslink-mqtt /var/lib /var/log /work "
             "/var/lib/roslink-mqtt-bridge /var/log/roslink-mqtt-bridge /tmp /var/tmp /dev/shm; do "
             "touch $p/.probe 2>/dev/null && echo writable $p && rm $p/.probe; done; "
             "ls /home /root >/dev/null 2>&1 || echo homes-closed; "
             "head -c1 /etc/roslink-mqtt/robots.yaml >/dev/null && echo fleet-readable; "
             "head -c1 /etc/roslink-mqtt/bridge.env >/dev/null 2>&1 || echo env-file-closed; "
             "grep -q '^NoNewPrivs:.*1' /proc/self/status && echo no-new-privs; id -u")
    done = subprocess.run(sandboxed(fake, keep, ["sh", "-c", probe],
                                    writable={state: "/var/lib/roslink-mqtt-bridge",
                                              logs: "/var/log/roslink-mqtt-bridge"}),
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n") == [
        "writable /var/lib/roslink-mqtt-bridge", "writable /var/log/roslink-mqtt-bridge", "writable /tmp",
        "writable /var/tmp", "writable /dev/shm", "homes-closed", "fleet-readable", "env-file-closed",
        "no-new-privs", str(RUN_AS), ""], done.stdout + done.stderr


class Notifications:
    """systemd's notify socket, in the abstract namespace (shared across mount namespaces)."""

    def __init__(self) -> None:
        self.name = f"roslink-test-notify-{os.getpid()}-{time.monotonic_ns()}"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + self.name)
        self.sock.settimeout(0.2)
        self.seen: list[str] = []

    @property
    def address(self) -> str:
        return "@" + self.name

    def wait_for(self, wanted: str, timeout: float, proc: subprocess.Popen) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if any(wanted in m for m in self.seen):
                return True
            try:
                self.seen.append(self.sock.recv(4096).decode())
            except TimeoutError:
                if proc.poll() is not None:
                    return False
        return any(wanted in m for m in self.seen)

    def close(self) -> None:
        self.sock.close()


def run_bridge_unit(unit_text: str, tmp_path: Path, name: str, port: int, notify: Notifications,
                    fake: Path, keep: Path | None) -> tuple[subprocess.Popen, Path]:
    pairs = service_section(unit_text)
    env_file = environment_file(fake / "etc" / "roslink-mqtt" / "bridge.env")
    args = env_file.get("ROSLINK_BRIDGE_ARGS", "")
    assert "--url " in args, "the shipped bridge.env names a broker in ROSLINK_BRIDGE_ARGS"
    assert "ROSLINK_PASSWORD" in env_file, "the shipped bridge.env uses the one connection vocabulary"
    extra = {  # what an admin writes into bridge.env, pointed at this test's broker
        "ROSLINK_PASSWORD": DEMO_PASSWORDS["turtle1"],
        "ROSLINK_BRIDGE_ARGS": re.sub(r"--url \S+", f"--url mqtt://127.0.0.1:{port}", args)
        + " --ros-args -r __ns:=/robot1",
        "NOTIFY_SOCKET": notify.address,
    }
    env = service_env(pairs, fake, extra)
    argv = exec_start(pairs, env)
    assert argv[:5] == [f"{PREFIX}/.venv/bin/roslink-mqtt-bridge", "--config", "/etc/roslink-mqtt/robots.yaml",
                        "--robot", "turtle1"], argv
    writable = {}
    for key, base in (("StateDirectory", "/var/lib"), ("LogsDirectory", "/var/log")):
        for directory in values(pairs, key):
            writable[writable_dir(tmp_path / f"{name}-{key}")] = f"{base}/{directory}"
    workdir = specifiers(one(pairs, "WorkingDirectory", "/"))
    log = tmp_path / f"{name}.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(sandboxed(fake, keep, argv, workdir=workdir, writable=writable), env=env,
                                stdout=out, stderr=subprocess.STDOUT)
    return proc, log


def stop(proc: subprocess.Popen, timeout: float = 5.0) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)  # KillSignal=SIGTERM, TimeoutStopSec=5
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            return -9
    return proc.returncode


def robot_node(fake: Path, keep: Path | None, log: Path, *, same_user: bool) -> subprocess.Popen:
    """The robot's own ROS node (the simulated turtle, in /robot1): as the bridge's user, or as root."""
    argv = ["-m", "roslink_mqtt.sim", "--ros-args", "-r", "__ns:=/robot1"]
    env = {"PATH": "/usr/bin:/bin", "HOME": "/nonexistent", "ROS_LOG_DIR": "/tmp/ros-log",
           **{key: os.environ[key] for key in LOCAL_DDS}}
    with open(log, "wb") as out:  # in the same sandbox: the user is the only difference
        return subprocess.Popen(sandboxed(fake, keep, [f"{PREFIX}/.venv/bin/python", *argv],
                                          uid=RUN_AS if same_user else 0), env=env,
                                stdout=out, stderr=subprocess.STDOUT)


def test_bridge_unit_starts_in_its_sandbox_and_the_old_one_did_not(tmp_path) -> None:
    fake, keep = fake_root(tmp_path, free_port())
    notify = Notifications()
    try:
        with mosquitto_with_logins(tmp_path) as port, TestClient(port, "admin", DEMO_PASSWORDS["admin"]) as admin:
            assert admin.connect() == 0
            admin.subscribe("roslink/turtle1/#")
            # Before the fix: rcl cannot create ~/.ros/log (HOME=/home/robot is hidden, / is read-only).
            t0 = time.monotonic()
            old, old_log = run_bridge_unit(OLD_BRIDGE_UNIT, tmp_path, "old", port, notify, fake, keep)
            try:
                old.wait(20)
            finally:
                stop(old)
            output = old_log.read_text(errors="replace")
            assert old.returncode != 0, output
            assert "RCLError: failed to initialize logging" in output, output
            assert "Failed to create log directory '/home/robot/.ros/log'" in output, output
            assert not any(m.startswith("READY=1") for m in notify.seen), notify.seen
            print(f"old unit: exit {old.returncode} after {time.monotonic() - t0:.1f} s: failed to initialize logging")

            # The shipped unit, next to the robot's ROS node running as the same user: READY, connected, its
            # heartbeat and the robot's odometry reach the broker; SIGTERM stops it cleanly.
            sim = robot_node(fake, keep, tmp_path / "sim.log", same_user=True)
            t0 = time.monotonic()
            new, new_log = run_bridge_unit(BRIDGE_UNIT.read_text(), tmp_path, "new", port, notify, fake, keep)
            try:
                connected = notify.wait_for("STATUS=connected to mqtt://127.0.0.1", 30, new)
                up = time.monotonic() - t0
                assert connected, f"{notify.seen}\n{new_log.read_text(errors='replace')}"
                assert any(m.startswith("READY=1") for m in notify.seen), notify.seen
                admin.wait_for(lambda m: m.topic == "roslink/turtle1/heartbeat", timeout=10)
                try:
                    admin.wait_for(lambda m: m.topic == "roslink/turtle1/state/global_motion", timeout=15)
                except TimeoutError:
                    pytest.fail(f"no odometry from the robot's node\n{new_log.read_text(errors='replace')}\n"
                                f"{(tmp_path / 'sim.log').read_text(errors='replace')}")
                flowing = time.monotonic() - t0
                stop(sim)
                # The robot's node as another user (root): Fast DDS's shared memory connects nothing, and the
                # bridge, though online, hears no odometry. Hence install.sh --bridge-user.
                sim = robot_node(fake, keep, tmp_path / "sim-root.log", same_user=False)
                admin.drain(1.0)
                moved = [m for m in admin.drain(5.0) if m.topic == "roslink/turtle1/state/global_motion"]
                root_log = (tmp_path / "sim-root.log").read_text(errors="replace")
                assert "simulated robot ready" in root_log and sim.poll() is None, root_log
                assert not moved, "odometry crossed users: bridge/README.md's --bridge-user advice is out of date"
                assert new.poll() is None, new_log.read_text(errors="replace")
            finally:
                code = stop(new)
                stop(sim)
            notify.wait_for("STOPPING=1", 2, new)
            output = new_log.read_text(errors="replace")
            assert code == 0, output
            assert "STOPPING=1" in notify.seen, notify.seen
            assert "Traceback" not in output, output
            print(f"shipped unit: connected {up:.1f} s, odometry {flowing:.1f} s after start, exit {code} on SIGTERM")
    finally:
        notify.close()
    # rcl's log went where ROS_LOG_DIR points, into the unit's LogsDirectory.
    assert list((tmp_path / "new-LogsDirectory").glob("*.log")), list((tmp_path / "new-LogsDirectory").iterdir())


def test_broker_unit_starts_in_its_sandbox(tmp_path) -> None:
    port = free_port()
    fake, keep = fake_root(tmp_path, port)
    pairs = service_section(BROKER_UNIT.read_text())
    env = service_env(pairs, fake, {})
    argv = exec_start(pairs, env)
    assert argv == [f"{PREFIX}/.venv/bin/roslink-mqtt-broker", "--config", "/etc/roslink-mqtt/robots.yaml"], argv
    log = tmp_path / "broker.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(sandboxed(fake, keep, argv), env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_for_port(port, timeout=20)
    except TimeoutError:
        pytest.fail(log.read_text(errors="replace"))
    finally:
        code = stop(proc)
    assert code == 0, log.read_text(errors="replace")


def dry_run(*args: str) -> str:
    """install.sh --dry-run ARGS with a configuration of one's own (a robot file of the demo fleet: not the demo fleet
    itself, which install.sh refuses)."""
    from roslink_mqtt.config.split import split_fleet

    config = split_fleet(CONFIG, tempfile.mkdtemp(), ["turtle1"])[0]
    done = subprocess.run(["bash", str(INSTALL), "--dry-run", "--config", str(config), *args], capture_output=True,
                          text=True, timeout=30, cwd=ROOT)
    if "no python3.11 found" in done.stderr:
        pytest.skip("install.sh needs a system Python 3.11 (none here)")
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def test_install_dry_run_creates_what_the_units_name() -> None:
    before = Path(PREFIX).exists(), Path("/etc/roslink-mqtt").exists()
    out = dry_run("bridge", "broker")
    assert (Path(PREFIX).exists(), Path("/etc/roslink-mqtt").exists()) == before, "--dry-run changed something"
    commands = [line[2:] for line in out.splitlines() if line.startswith("+ ")]
    text = "\n".join(commands)
    for unit in (BRIDGE_UNIT, BROKER_UNIT):
        pairs = service_section(unit.read_text())
        user = one(pairs, "User")
        if f"user {user} exists" not in out:  # a host where it was installed before
            assert re.search(rf"^useradd --system .*--home-dir {PASSWD_HOME[user]} .*{user}$", text, re.M), out
        binary = shlex.split(one(pairs, "ExecStart"))[0]
        assert binary.startswith(f"{PREFIX}/.venv/bin/"), binary
        assert f"-m venv {PREFIX}/.venv" in text or f"venv {PREFIX}/.venv exists" in out, out
        assert f"/etc/systemd/system/{unit.name}" in text, out
        assert f"sudo systemctl enable --now {unit.stem}" in out, out
        for config in re.findall(r"/etc/roslink-mqtt/\S+", one(pairs, "ExecStart")):
            assert config in text or f"keeping {config}" in out, (config, out)
    bridge = service_section(BRIDGE_UNIT.read_text())
    for group in values(bridge, "SupplementaryGroups"):
        assert f"groupadd --system {group}" in text or f"group {group} exists" in out, out
    env_file = one(bridge, "EnvironmentFile")
    assert f"-m 600 -o root -g root <(render bridge/roslink-mqtt-bridge.env) {env_file}" in text \
        or f"keeping {env_file}" in out, out
    assert re.search(r"pip install --upgrade \S+\\\[bridge\\,broker\\\]$", text, re.M), out

    other = dry_run("--prefix", "/srv/roslink", "--bridge-user", "turtlebot", "bridge", "broker")
    assert "/srv/roslink/.venv/bin/pip install" in other, other
    rendered = {}  # unit -> the lines install.sh changes in it
    for block in re.split(r"(?m)^\+ ", other):
        unit = re.search(r"/etc/systemd/system/(\S+)", block.splitlines()[0]) if block else None
        if unit:
            rendered[unit.group(1)] = re.findall(r"(?m)^#   rendered: (.*)$", block)
    assert rendered["roslink-mqtt-bridge.service"][:2] == [
        "User=turtlebot", "ExecStart=/srv/roslink/.venv/bin/roslink-mqtt-bridge --config /etc/roslink-mqtt/robots.yaml "
        "--robot ${ROSLINK_ROBOT} $ROSLINK_BRIDGE_ARGS"], other
    broker_lines = rendered["roslink-mqtt-broker.service"]
    assert "ExecStart=/srv/roslink/.venv/bin/roslink-mqtt-broker --config /etc/roslink-mqtt/robots.yaml" \
        in broker_lines and not any(line.startswith("User=") for line in broker_lines), other
    broker = dry_run("broker")  # as broker/README.md shows it
    assert "/etc/systemd/system/roslink-mqtt-broker.service" in broker and "bridge.env" not in broker, broker
    assert re.search(r"pip install --upgrade \S+\\\[broker\\\]$", broker, re.M), broker


def test_install_refuses_what_the_units_cannot_run() -> None:
    no_etc = [] if Path("/etc/roslink-mqtt/robots.yaml").exists() else [
        (["bridge"], "no configuration: pass --config FILE")]  # a host where it was installed keeps its file
    for args, reason in ((["--prefix", "/home/me/roslink", "bridge"], "ProtectHome"),
                         (["--bridge-user", "Not A User", "bridge"], "not a user name"),
                         ([], "say what to install"),
                         (["--config", str(CONFIG), "broker"], "is the demo fleet, whose passwords are public"),
                         *no_etc):
        done = subprocess.run(["bash", str(INSTALL), "--dry-run", *args], capture_output=True, text=True,
                              timeout=30)
        assert done.returncode == 2 and reason in done.stderr, (args, done.stdout + done.stderr)
