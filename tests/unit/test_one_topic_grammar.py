"""No module outside ``roslink_mqtt.topics`` splits or formats a topic string (issue 14, "one topic grammar").

Topics, filters and ACL patterns are built with :class:`roslink_mqtt.topics.TopicTree` and read with its
``parse``, so a new verb is added in one place. This scan reads the source of the package, the benchmarks
and the examples and fails on either sign of a second grammar:

* a ``split``/``partition``/``removeprefix``… at ``/`` (parsing a topic by hand), or
* a string literal that spells topic levels (``"…/from/…"``, ``f"{robot}/state/…"``, ``"cmd/twist"``).

Prose (a string spanning several lines: rendered documentation) is not a topic. ROS interface names
(``pkg/msg/Type``) are not topics either: the modules that read them are listed with that reason.
"""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("roslink_mqtt", "bench", "examples")
GRAMMAR = "roslink_mqtt/topics.py"
NOT_TOPICS = {  # module: why its "/" handling is not about topics
    "roslink_mqtt/config/interfaces.py": "ROS interface names (pkg/msg/Type)",
    "roslink_mqtt/bridge/ros_types.py": "ROS interface names (pkg/msg/Type)",
}
SPLIT_AT_SLASH = re.compile(
    r"""\.(r?split|r?partition|removeprefix|removesuffix|startswith|endswith)\(\s*f?["'][^"']*/""")
LEVELS = "roslink|state|from|to|heartbeat|operators|" + "|".join(
    ("cmd", "call", "reply", "provide", "request", "response", "advertise", "error", "access"))
# a level of the tree joined to another by "/" (prose such as "on state/ack" is words, not a topic being built)
TOPIC_LEVELS = re.compile(rf"(^|[/{{}}])({LEVELS})/|/({LEVELS})($|/)|/[+#]$|/\+/|^\+/")  # …or a filter
QUOTES = re.compile(r"^[rbfRBF]*('|\")(?P<body>.*)\1$", re.S)


def sources() -> list[Path]:
    return sorted(p for d in SCANNED for p in (ROOT / d).rglob("*.py"))


def offences(path: Path) -> list[str]:
    rel = path.relative_to(ROOT).as_posix()
    if rel == GRAMMAR or rel in NOT_TOPICS:
        return []
    text = path.read_text()
    found = [f"{rel}:{n}: splits at '/': {line.strip()}" for n, line in enumerate(text.splitlines(), 1)
             if SPLIT_AT_SLASH.search(line)]
    tokens = [t for t in tokenize.generate_tokens(io.StringIO(text).readline)
              if t.type not in (tokenize.NL, tokenize.COMMENT)]
    for i, tok in enumerate(tokens):
        if tok.type != tokenize.STRING or "\n" in tok.string:
            continue  # prose: docstrings and rendered documentation span lines
        if i and tokens[i - 1].type in (tokenize.INDENT, tokenize.DEDENT, tokenize.NEWLINE):
            continue  # a one-line docstring
        body = QUOTES.match(tok.string)
        if TOPIC_LEVELS.search(body.group("body") if body else tok.string):
            found.append(f"{rel}:{tok.start[0]}: spells a topic: {tok.string[:90]}")
    return found


def test_nothing_outside_topics_splits_or_formats_a_topic() -> None:
    problems = [line for path in sources() for line in offences(path)]
    assert not problems, ("build and parse topics with roslink_mqtt.topics.TopicTree:\n" + "\n".join(problems))


def test_the_scan_catches_a_second_grammar(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The scan itself can fail: each way of restating the grammar is caught."""
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    bad = tmp_path / "roslink_mqtt" / "bad.py"
    bad.parent.mkdir()
    for line in ['kind, _, leaf = name.partition("/")', 'verb = topic.split("/")[3]',
                 'topic = f"{prefix}/{robot}/from/{user}/cmd/twist"', 'leaf = "cmd/twist"',
                 'pattern = f"{p}/{OPERATORS}/{user}/#"', 'if topic.endswith("/reply/reset"): pass',
                 'x = f"{root}/state/"']:
        bad.write_text(line + "\n")
        assert offences(bad), line
    bad.write_text('message = f"{robot}/{service}: {reason}"\nprefix = "roslink"\n')
    assert not offences(bad)
