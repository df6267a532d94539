"""No module outside ``roslink_mqtt.topics`` builds or splits a topic (issue 14 "one topic grammar", issue 27).

Topics, filters and ACL patterns are built with :class:`roslink_mqtt.topics.TopicTree` and read with its
``parse``, so a new verb is added in one place. ROS names (``pkg/msg/Type``, ``/ns/node``) are read in
:mod:`roslink_mqtt.ros_names` only. This check reads the syntax tree of the package, the benchmarks and the
examples (not their text: a regular expression is easy to walk around) and fails on each way of restating the
grammar:

* splitting, partitioning, stripping, counting or testing a string at ``/`` (``t.split("/")``, ``SEPARATOR``,
  ``"/srv/" in name``);
* joining with ``/`` (``"/".join([...])``);
* formatting a path: an f-string or a ``+`` whose text has ``/`` and no space (``f"{p}/{robot}/state"``,
  ``prefix + "/" + robot``), whatever names or constants fill it in;
* a string that spells levels of the tree (``"cmd/twist"``, ``"…/from/…"``, ``"roslink/+/heartbeat"``);
* reading a level by its position (``levels(t)[2] == "from"``, ``parts[0] in ("state", …)``);
* importing what ``topics`` keeps private.

Prose is not a topic: docstrings, strings with a newline, f-strings with a space (messages such as
``f"{robot}/{service}: {reason}"``) and URLs (``mqtt://``) are not checked.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("roslink_mqtt", "bench", "examples")
OWNERS = {  # the modules whose job is "/" handling, and why
    "roslink_mqtt/topics.py": "the topic grammar",
    "roslink_mqtt/ros_names.py": "ROS names: interface types (pkg/msg/Type) and node, topic and service names",
}
SLASHY_METHODS = {"split", "rsplit", "partition", "rpartition", "removeprefix", "removesuffix", "startswith",
                  "endswith", "count", "strip", "lstrip", "rstrip", "find", "rfind", "index", "rindex", "replace"}
VERB_WORDS = ("cmd", "call", "reply", "provide", "request", "response", "advertise", "error", "notice", "access",
              "goal", "cancel", "feedback", "result", "param", "log", "declare", "control")
TREE_WORDS = frozenset(("roslink", "state", "from", "to", "heartbeat", "operators") + VERB_WORDS)
LEVELS = "|".join(sorted(TREE_WORDS))
# a level of the tree joined to another by "/" (prose such as "on state/ack" is words, not a topic being built)
TOPIC_LEVELS = re.compile(rf"(^|[/{{}}])({LEVELS})/|/({LEVELS})($|/)|/[+#]$|/\+/|^\+/")  # …or a filter
HOLE = "{}"  # where an f-string's formatted value stood


def _is_slash(node: ast.AST) -> bool:
    """A "/" constant, or the grammar's separator by name."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return "/" in node.value
    return isinstance(node, ast.Name | ast.Attribute) and (getattr(node, "id", None) or getattr(node, "attr", "")) \
        == "SEPARATOR"


def _text(node: ast.AST) -> str | None:
    """The text of a string constant or f-string (formatted values as ``{}``); None for anything else."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else HOLE for v in node.values)
    return None


def _is_prose(text: str) -> bool:
    """Text that is no topic: prose, a URL, a Zenoh locator (``tcp/127.0.0.1:7447``: bench/zenoh_peer.py)."""
    return "\n" in text or " " in text or "://" in text or text.startswith(ZENOH_LOCATOR)


ZENOH_LOCATOR = ("tcp/", "udp/", "tls/", "quic/")


def _docstrings(tree: ast.AST) -> set[int]:
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant | ast.JoinedStr):
            out.add(id(node.value))  # a bare string statement: a docstring or a comment in quotes
    return out


def _concat_parts(node: ast.BinOp) -> Iterator[ast.AST]:
    for side in (node.left, node.right):
        if isinstance(side, ast.BinOp) and isinstance(side.op, ast.Add):
            yield from _concat_parts(side)
        else:
            yield side


def offences_in(source: str, rel: str) -> list[str]:
    tree = ast.parse(source)
    skip = _docstrings(tree)
    found: list[str] = []

    def say(node: ast.AST, what: str) -> None:
        found.append(f"{rel}:{getattr(node, 'lineno', 0)}: {what}: {ast.unparse(node)[:100]}")

    in_fstring: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            in_fstring.update(id(v) for v in node.values)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").endswith("topics"):
            private = [a.name for a in node.names if a.name.startswith("_") or a.name == "SEPARATOR"]
            if private:
                say(node, f"imports what topics keeps to itself ({', '.join(private)})")
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            method = node.func.attr
            if method in SLASHY_METHODS and node.args and _is_slash(node.args[0]):
                say(node, "splits or tests a string at '/'")
            elif method == "join" and _is_slash(node.func.value):
                say(node, "joins with '/'")
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
            texts = [_text(p) for p in _concat_parts(node)]
            if any(t is not None and "/" in t for t in texts) and not any(t is not None and _is_prose(t)
                                                                          for t in texts):
                say(node, "formats a path with +")
        elif isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            if any(isinstance(op, ast.In | ast.NotIn) for op in node.ops) and _is_slash(node.left) \
                    and not _is_prose(_text(node.left) or ""):
                say(node, "tests a string for '/' levels")
            words = [s for s in sides for w in _words(s) if w in TREE_WORDS]
            if words and any(isinstance(s, ast.Subscript) and not _keyed_by_string(s) for s in sides):
                say(node, "reads a level of the tree by its position")
        if id(node) in skip or id(node) in in_fstring:
            continue
        text = _text(node)
        if text is None or _is_prose(text):
            continue
        if isinstance(node, ast.JoinedStr) and "/" in text.replace(HOLE, ""):
            say(node, "formats a path")
        elif TOPIC_LEVELS.search(text):
            say(node, "spells a topic")
    return found


def _words(node: ast.AST) -> list[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)]
    return []


def _keyed_by_string(node: ast.Subscript) -> bool:
    """``body["kind"]`` is a lookup by key, not a level read by position."""
    return isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str)


def sources() -> list[Path]:
    return sorted(p for d in SCANNED for p in (ROOT / d).rglob("*.py"))


def offences(path: Path) -> list[str]:
    rel = path.relative_to(ROOT).as_posix()
    return [] if rel in OWNERS else offences_in(path.read_text(), rel)


def test_nothing_outside_topics_splits_or_formats_a_topic() -> None:
    problems = [line for path in sources() for line in offences(path)]
    assert not problems, ("build and read topics with roslink_mqtt.topics (TopicTree), ROS names with "
                          "roslink_mqtt.ros_names:\n" + "\n".join(problems))


EVASIONS = [
    'kind, _, leaf = name.partition("/")',
    'verb = topic.split("/")[3]',
    'verb = topic.split(SEPARATOR)[3]',
    'topic = "/".join([prefix, robot, "from", user])',
    'topic = SEPARATOR.join((prefix, robot))',
    'topic = f"{prefix}/{robot}/from/{user}/cmd/twist"',
    'topic = f"{PREFIX}/{robot}/{FROM}/{user}"',
    'topic = prefix + "/" + robot',
    'leaf = "cmd/twist"',
    'pattern = f"{p}/{OPERATORS}/{user}/#"',
    'if topic.endswith("/reply/reset"): pass',
    'x = f"{root}/state/"',
    'mine = levels(t)[2] == "from"',
    'mine = parts[0] in ("state", "heartbeat")',
    'from roslink_mqtt.topics import _levels',
    'from ..topics import SEPARATOR',
    'n = name.count("/")',
    'ok = "/srv/" not in name',
]
PROSE = [
    'message = f"{robot}/{service}: {reason}"',
    'prefix = "roslink"',
    'url = f"mqtt://{host}:{port}"',
    'kind = body["kind"] == "state"',
    'def f():\n    """Reads roslink/<robot>/state/<name>."""\n',
    'text = "send cmd/arm to resume"',
]


@pytest.mark.parametrize("line", EVASIONS)
def test_the_check_catches_each_way_of_restating_the_grammar(line: str) -> None:
    assert offences_in(line + "\n", "bad.py"), line


@pytest.mark.parametrize("line", PROSE)
def test_prose_and_lookups_are_not_topics(line: str) -> None:
    assert not offences_in(line + "\n", "fine.py"), line
