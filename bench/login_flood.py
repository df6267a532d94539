"""Benchmark: a password-guessing flood beside a driving fleet — what it costs the robots' traffic.

    .venv/bin/python bench/login_flood.py [--robots 50] [--guessers 0,25,100] [--seconds 8] [--plot PATH]

The fleet is bench/fleet.py's (every robot and its operator on their own connections: 10 Hz motion and twists,
1 Hz retained heartbeats and presence) on the embedded broker. The fleet file also has 20 staff logins and a
``latecomer``, their passwords hashed at the deployed strength (PBKDF2, 210,000 iterations: what makes a guess
cost the broker). Beside the fleet, ``N`` guessers, each from a loopback address of its own (127.0.4.i: the
per-address throttle sees N strangers), send wrong passwords back to back — for the staff's real logins and for
made-up ones, in turn — and abandon each attempt after 50 ms: no login needed, the broker is left with the work.
Half way through the window the latecomer, who never logged in before, logs in with the right password, retrying
on "server unavailable" as clients do. (The fleet's own passwords are hashed weakly, as in bench/fleet.py, so
that the fleet connects in a second; a verified login does not hash again.) The guessers are Python threads in a
process of their own on the same two cores as the broker.

Per flood size: the fleet's command (operator -> robot) and state (robot -> monitor) latency p50/p99, delivered
share, connections the broker ended, guesses made and how they were answered, the latecomer's time to get in, and
the broker's CPU split into its event loop (the main thread: every robot's traffic) and its other threads (password
checks: broker/hashing.py). The row with 0 guessers is the quiet reference, measured in the same run.
Goals (issue 48): command p99 <= 2x quiet and <= 20 ms, password checks <= one core, no connection lost, the
latecomer in within 2 s. Never asserts.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import fleet as fb  # (bench/fleet.py: the fleet, its load generator and its step)
import latency as lat
import orjson
from _support import PROC, TICKS

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PLOT = ROOT / "docs" / "performance" / "login_flood.png"
LATECOMER, LATECOMER_PASSWORD = "latecomer", "latecomer-password"
STAFF = [f"staff{i:02d}" for i in range(20)]  # real logins with deployed-strength passwords: what guessers aim at
ABANDON_AFTER = 0.05  # s a guesser waits for its CONNACK
GOAL_P99_MS, GOAL_FACTOR, GOAL_LOGIN_S = 20.0, 2.0, 2.0


# -- the guessers (a child process) ----------------------------------------------------------------------------
def connect_packet(client_id: str, username: str, password: str) -> bytes:
    """An MQTT 3.1.1 CONNECT with a login (clean session, keep-alive 30 s)."""
    def utf8(text: str) -> bytes:
        raw = text.encode()
        return len(raw).to_bytes(2, "big") + raw

    body = utf8("MQTT") + bytes([4, 0xC2]) + (30).to_bytes(2, "big") + utf8(client_id) + utf8(username) + utf8(password)
    head, n = bytearray([0x10]), len(body)
    while True:
        byte, n = n % 128, n // 128
        head.append(byte | 0x80 if n else byte)
        if not n:
            return bytes(head) + body


def attempt(port: int, source: str, username: str, password: str, wait: float) -> int | None:
    """One login; the CONNACK's return code, or None when none came within ``wait`` s (abandoned)."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=wait, source_address=(source, 0)) as sock:
            sock.sendall(connect_packet(f"c{time.monotonic_ns()}", username, password))
            answer = b""
            while len(answer) < 4:
                piece = sock.recv(4 - len(answer))
                if not piece:
                    return None
                answer += piece
            return answer[3]
    except OSError:
        return None


def thread_cpu(pid: int) -> tuple[float, float]:
    """(the main thread's CPU seconds — the broker's event loop —, every other thread's), from /proc."""
    main = others = 0.0
    try:
        tasks = list((PROC / str(pid) / "task").iterdir())
    except OSError:
        return float("nan"), float("nan")
    for task in tasks:
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        seconds = (int(fields[11]) + int(fields[12])) / TICKS
        if task.name == str(pid):
            main += seconds
        else:
            others += seconds
    return main, others


def guess_main(args: argparse.Namespace) -> int:
    """``--count`` guessers from ``--start-at - WARMUP`` to the window's end; the latecomer half way."""
    window = (args.start_at, args.start_at + args.seconds)
    users = STAFF
    answers: dict[str, int] = {}
    lock, stop = threading.Lock(), threading.Event()

    def guesser(i: int) -> None:
        n = 0
        while not stop.is_set():
            n += 1
            user = users[(i * 7 + n) % len(users)] if n % 2 else f"nobody-{i}-{n}"
            code = attempt(args.port, f"127.0.4.{i}", user, f"guess-{n}", ABANDON_AFTER)
            with lock:
                key = "abandoned" if code is None else str(code)
                answers[key] = answers.get(key, 0) + 1

    time.sleep(max(0.0, window[0] - fb.WARMUP - time.monotonic()))
    threads = [threading.Thread(target=guesser, args=(i,), daemon=True) for i in range(1, args.count + 1)]
    for t in threads:
        t.start()
    time.sleep(max(0.0, window[0] - time.monotonic()))
    cpu0 = thread_cpu(args.broker_pid)
    time.sleep(max(0.0, window[0] + args.seconds / 2 - time.monotonic()))
    began, codes = time.monotonic(), []
    while time.monotonic() - began < 10:
        codes.append(attempt(args.port, "127.0.5.1", LATECOMER, LATECOMER_PASSWORD, 10.0))
        if codes[-1] == 0:
            break
        time.sleep(0.2)  # a client's retry after "server unavailable"
    latecomer = time.monotonic() - began if codes and codes[-1] == 0 else float("inf")
    time.sleep(max(0.0, window[1] - time.monotonic()))
    cpu1 = thread_cpu(args.broker_pid)
    stop.set()
    for t in threads:
        t.join(2)
    args.out.write_bytes(orjson.dumps({
        "answers": answers, "latecomer_s": latecomer if latecomer != float("inf") else None,
        "latecomer_codes": codes, "loop_cpu": 100 * (cpu1[0] - cpu0[0]) / args.seconds,
        "other_cpu": 100 * (cpu1[1] - cpu0[1]) / args.seconds}))
    return 0


# -- one flood size ----------------------------------------------------------------------------------------------
def run(guessers: int, robots: int, seconds: float, reader: str, work: Path, env: dict[str, str]) -> dict[str, Any]:
    out = work / f"guess-{guessers}.json"

    def during(phase: Any, port: int, start_at: float, step: Any) -> None:
        lat.start_child(phase, [sys.executable, str(Path(__file__).resolve()), "--guess-worker", "--count",
                                str(guessers), "--robots", str(robots), "--port", str(port), "--start-at",
                                repr(start_at), "--seconds", str(seconds), "--broker-pid",
                                str(step.broker_pids[0]), "--out", str(out)], work / f"guess-{guessers}.log", env)

    step = fb.run_step("embedded", robots, work, env, seconds, reader=reader, users=strong_users(), during=during)
    for _ in range(100):  # the guess worker writes its report at the window's end
        if out.exists():
            break
        time.sleep(0.1)
    report = orjson.loads(out.read_bytes()) if out.exists() else {}
    return {"guessers": guessers, "step": step, **report}


def fmt(row: dict[str, Any], quiet_p99: float) -> str:
    step = row["step"]
    answers = row.get("answers", {})
    guesses = sum(answers.values())
    refused = answers.get("5", 0) + answers.get("4", 0)
    busy, abandoned = answers.get("3", 0), answers.get("abandoned", 0)
    cmd_p99 = step.pct(step.cmd_ms, 99)
    late = row.get("latecomer_s")
    goals = [cmd_p99 <= GOAL_P99_MS, not row["guessers"] or cmd_p99 <= GOAL_FACTOR * quiet_p99,
             step.lost_connections == 0, step.cmd_received >= step.cmd_sent and step.state_received >= step.state_sent,
             late is not None and late <= GOAL_LOGIN_S, row.get("other_cpu", 0.0) <= 100]
    return (f"{row['guessers']:>8} {guesses:>8} {refused:>8} {busy:>6} {abandoned:>9} "
            f"{step.cmd_received:>6}/{step.cmd_sent:<6} {step.pct(step.cmd_ms, 50):6.1f} {cmd_p99:7.1f} "
            f"{step.state_received:>6}/{step.state_sent:<6} {step.pct(step.state_ms, 50):6.1f} "
            f"{step.pct(step.state_ms, 99):7.1f} {step.lost_connections:>5} "
            f"{(late * 1000 if late is not None else float('nan')):9.0f} {row.get('loop_cpu', float('nan')):6.0f} "
            f"{row.get('other_cpu', float('nan')):7.0f}  {'met' if all(goals) else 'MISS'} {step.note}")


HEADER = (f"{'guessers':>8} {'guesses':>8} {'refused':>8} {'busy':>6} {'abandoned':>9} {'commands':>13} "
          f"{'p50':>6} {'p99':>7} {'state':>13} {'p50':>6} {'p99':>7} {'lost':>5} {'login ms':>9} {'loop %':>6} "
          f"{'other %':>7}  goals")


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=100)
    labels = [str(r["guessers"]) for r in rows]
    x = range(len(rows))
    ax.bar([i - 0.2 for i in x], [r["step"].pct(r["step"].cmd_ms, 99) for r in rows], 0.4, label="commands p99")
    ax.bar([i + 0.2 for i in x], [r["step"].pct(r["step"].state_ms, 99) for r in rows], 0.4, label="state p99")
    ax.axhline(GOAL_P99_MS, color="grey", linestyle="--", linewidth=1, label=f"goal {GOAL_P99_MS:.0f} ms")
    ax.set_xticks(list(x), labels)
    ax.set_xlabel("guessers (each from its own address)")
    ax.set_ylabel("ms")
    ax.set_title(f"A fleet of {rows[0]['step'].robots} beside a password-guessing flood")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="4 s windows, 0 and 25 guessers")
    p.add_argument("--robots", type=int, default=50, help="robots, each with its operator (default: %(default)s)")
    p.add_argument("--guessers", default="0,25,100", help="flood sizes, comma-separated (default: %(default)s)")
    p.add_argument("--seconds", type=float, default=8.0, help="measured window per size (default: %(default)s)")
    p.add_argument("--reader", choices=("inline", "amqtt"), default="inline", help="the embedded broker's reader")
    p.add_argument("--plot", type=Path, default=DEFAULT_PLOT, help="(default: %(default)s)")
    p.add_argument("--guess-worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--count", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--port", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--start-at", type=float, default=0.0, help=argparse.SUPPRESS)
    p.add_argument("--broker-pid", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, default=Path("guess.json"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.quick:
        args.seconds, args.guessers = 4.0, "0,25"
    try:
        args.sizes = [int(n) for n in args.guessers.split(",")]
    except ValueError:
        p.error("--guessers is a comma-separated list of numbers")
    if any(not 0 <= n <= 250 for n in args.sizes):
        p.error("--guessers: 0..250 each (one loopback address per guesser)")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.guess_worker:
        return guess_main(args)
    env = dict(os.environ)
    rows: list[dict[str, Any]] = []
    print(f"a fleet of {args.robots} robots with their operators on the embedded broker ({args.reader} reader); "
          f"guesses aim at {len(STAFF)} staff logins (PBKDF2, {DEPLOYED_ITERATIONS:,} iterations) and made-up ones; "
          f"{args.seconds:g} s windows", flush=True)
    print(HEADER, flush=True)
    with tempfile.TemporaryDirectory(prefix="roslink-flood-") as tmp:
        for n in args.sizes:
            rows.append(run(n, args.robots, args.seconds, args.reader, Path(tmp), env))
            quiet = next((r for r in rows if r["guessers"] == 0), None)
            quiet_p99 = quiet["step"].pct(quiet["step"].cmd_ms, 99) if quiet else float("nan")
            print(fmt(rows[-1], quiet_p99), flush=True)
    print("refused: 'not authorized' or 'bad login' answered; busy: 'server unavailable' (the password checks' queue "
          "was full); abandoned: no answer within 50 ms; login ms: the latecomer's correct login, retries included; "
          "loop %: the broker's event loop (every robot's traffic), other %: its other threads (password checks)")
    plot(rows, args.plot)
    print(f"plot: {args.plot}")
    return 0


def _deployed_iterations() -> int:
    from roslink_mqtt.config.passwords import DEFAULT_ITERATIONS

    return DEFAULT_ITERATIONS


DEPLOYED_ITERATIONS = _deployed_iterations()
_HASHES: dict[str, str] = {}


def strong_users() -> dict[str, str]:
    """The staff and the latecomer, name -> hash at the deployed strength (hashed once per run)."""
    from roslink_mqtt.config.passwords import hash_password

    if not _HASHES:
        staff = hash_password("staff-password")
        _HASHES.update({name: staff for name in STAFF})
        _HASHES[LATECOMER] = hash_password(LATECOMER_PASSWORD)
    return _HASHES

if __name__ == "__main__":
    sys.exit(main())
