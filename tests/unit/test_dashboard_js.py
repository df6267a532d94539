"""The dashboard speaks the protocol from its own declarations: the generated protocol.mjs is current, static/body.mjs
reads every body as protocol/body.py's lenient reader does, and static/topics.mjs builds and parses every topic as
roslink_mqtt/topics.py does (run by node, case by case)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import orjson
import pytest

from roslink_mqtt.dashboard.protocol_js import OUTPUT, body_key, entry_key, render
from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.body import read
from roslink_mqtt.protocol.codec import decode_object
from roslink_mqtt.protocol.description import DESCRIPTION_ENTRIES
from roslink_mqtt.protocol.description import EXAMPLE as DESCRIPTION_EXAMPLE
from roslink_mqtt.protocol.messages import SPECS, FieldKind, MessageSpec
from roslink_mqtt.protocol.reference import _CONTROL_EXAMPLES, DOCUMENTED_BODIES
from roslink_mqtt.topics import TopicTree, Verb, param_events_node

pytestmark = pytest.mark.unit
ROOT = Path(__file__).resolve().parents[2]
# values that are wrong for most fields; no floats with a zero fraction (JSON in JavaScript cannot tell 1.0 from 1)
ODD_VALUES: list[Any] = [None, True, 7, -1, 1.5, "", "x", "operator", [], ["a"], [1], {}, {"a": 1}]


STATIC = OUTPUT.parent
MODULES = sorted(STATIC.rglob("*.mjs"))
# the protocol's readers (checked case by case against Python below) may look at a declaration's kind
PAGE_MODULES = [p for p in MODULES if p.name not in ("topics.mjs", "protocol.mjs", "body.mjs", "message.mjs")]


def test_the_page_has_no_topic_grammar_of_its_own() -> None:
    """The page builds and reads topics only through topics.mjs (a slash joined or split by hand is a second
    grammar), and restates none of the protocol's constants (they come from protocol.mjs)."""
    assert len(PAGE_MODULES) > 15, PAGE_MODULES
    for module in PAGE_MODULES:
        text = module.read_text()
        for pattern in (r'split\("/"\)', r'join\("/"\)', r'"/(from|to|state|heartbeat)/?"', r'\.kind === "',
                        r'\+ "/"', r"STALE_AFTER_MS\s*=\s*\d", r"\[\s*\"uninit\""):
            assert not re.search(pattern, text), f"{module.relative_to(STATIC)}: {pattern}"


def test_the_page_is_es_modules_without_a_global_closure() -> None:
    """No classic scripts of our own: index.html loads main.mjs as a module (MQTT.js is the one classic bundle),
    and no module leans on window globals for its inputs."""
    page = (STATIC / "index.html").read_text()
    assert re.findall(r'<script type="module" src="([^"]+)"', page) == ["main.mjs"]
    assert re.findall(r'<script src="([^"]+)"', page) == ["vendor/mqtt.min.js"]
    assert not list(STATIC.glob("*.js")), "the page's own code is .mjs modules"
    for module in MODULES:
        assert "window.ROSLINK" not in module.read_text() and "window.roslink" not in module.read_text(), module


def test_protocol_js_is_current() -> None:
    assert OUTPUT.read_text() == render(), "regenerate: python -m roslink_mqtt.dashboard.protocol_js --write"


def python_reads(cls: type, body: Any) -> Any:
    try:
        got = read(cls.FIELDS, body, shape="-", strict=False)  # type: ignore[attr-defined]
    except ProtocolError:
        return None
    return orjson.loads(orjson.dumps(got))  # tuples as arrays, as JSON has them


def cases() -> list[dict[str, Any]]:
    out = []
    for title, _topic, cls in DOCUMENTED_BODIES:
        example = orjson.loads(_CONTROL_EXAMPLES[cls].to_json())
        inputs: list[Any] = [example, {}, [], "x", {**example, "unknown": 1}]
        for field in cls.FIELDS:
            inputs.append({k: v for k, v in example.items() if k != field.name})
            inputs += [{**example, field.name: value} for value in ODD_VALUES]
        out += [{"body": body_key(title), "input": i, "expected": python_reads(cls, i)} for i in inputs]
    for key, entry in DESCRIPTION_ENTRIES:  # the description's entries, from the documented example's
        example = next(e.to_body() for e in getattr(DESCRIPTION_EXAMPLE, key))
        inputs = [example, {}, {**example, "unknown": 1}]
        for field in entry.FIELDS:
            inputs.append({k: v for k, v in example.items() if k != field.name})
            inputs += [{**example, field.name: value} for value in ODD_VALUES + [{"a": "b"}]]
        out += [{"body": entry_key(key), "input": i, "expected": python_reads(entry, i)} for i in inputs]
    return out


# a valid value of each payload field kind (no float with a zero fraction: see ODD_VALUES)
SAMPLE: dict[FieldKind, Any] = {FieldKind.INT: 3, FieldKind.FLOAT: 0.25, FieldKind.STR: "s", FieldKind.BOOL: True,
                                FieldKind.FLOAT_LIST: [0.5, -1.25], FieldKind.RANGE_LIST: [0.5, None],
                                FieldKind.INT_LIST: [1, 2], FieldKind.BASE64: "aGk="}
# wrong for most payload fields and list items; a header's out of bounds and unknown keys
ODD_ITEMS: list[Any] = [None, "x", 1.5, -1, True, 2**40]


def python_decodes(spec: MessageSpec, obj: Any) -> Any:
    try:
        return orjson.loads(orjson.dumps(decode_object(obj, spec.message_id).payload))
    except ProtocolError:
        return None


def message_cases() -> list[dict[str, Any]]:
    out = []
    for spec in SPECS:
        full = {f.name: SAMPLE[f.kind] for f in spec.fields}
        required = {f.name: SAMPLE[f.kind] for f in spec.fields if f.required}
        other = next(s for s in SPECS if s.message_id != spec.message_id)

        def envelope(payload: Any, **header: Any) -> dict[str, Any]:
            return {"message_id": int(spec.message_id), "system_id": 1, "sequence_number": 5, **header,  # noqa: B023
                    "payload": payload}

        inputs: list[Any] = [full, required, envelope(full), envelope(required), {}, [], "x", None,
                             {"payload": full}, {"message_id": int(spec.message_id)},
                             envelope(full, message_id=int(other.message_id)), envelope(full, message_id=250),
                             envelope(full, client_id="laptop"), envelope(full, client_id=""),
                             envelope(full, client_id="c" * 129), envelope(full, system_id=70_000),
                             envelope(full, sequence_number=-1), envelope(full, key="secret"),
                             envelope(full, roslink_version=True), {**full, "unknown": 1},
                             envelope({**full, "unknown": 1}), envelope([full])]
        for field in spec.fields:
            inputs.append(envelope({k: v for k, v in full.items() if k != field.name}))
            inputs += [envelope({**full, field.name: value}) for value in ODD_VALUES + ODD_ITEMS]
            if field.kind in (FieldKind.FLOAT_LIST, FieldKind.RANGE_LIST, FieldKind.INT_LIST):
                inputs += [envelope({**full, field.name: [value]}) for value in ODD_ITEMS]
        out += [{"message": spec.name, "input": i, "expected": python_decodes(spec, i)} for i in inputs]
    return out


def parsed_case(prefix: str, topic: str) -> dict[str, Any]:
    got = TopicTree(prefix).parse(topic)
    expected = None if got is None else {"kind": got.kind.value, "robot": got.robot, "user": got.user,
                                         "name": got.name, "client_id": got.client_id,
                                         "verb": got.verb.value if got.verb else None}
    return {"prefix": prefix, "topic": topic, "expected": expected, "leaf": got.leaf if got else None}


def topic_cases() -> dict[str, list[dict[str, Any]]]:
    built: list[dict[str, Any]] = []
    parsed: list[dict[str, Any]] = []
    for prefix in ("roslink", "fleet/site-a"):
        tree = TopicTree(prefix)

        def build(fn: str, args: list[str], expected: str) -> None:
            built.append({"prefix": prefix, "fn": fn, "args": args, "expected": expected})  # noqa: B023

        build("heartbeatFilter", [], tree.heartbeat_filter())
        build("heartbeatFilter", ["r1"], tree.heartbeat_filter("r1"))
        build("stateFilter", [], tree.state_filter())
        build("stateFilter", ["r1", "nav/+"], tree.state_filter("r1", "nav/+"))
        build("toUserFilter", ["+", "alice"], tree.to_user_filter("+", "alice"))
        build("operator", ["alice", "c1"], tree.operator("alice", "c1"))
        topics = [tree.heartbeat("r1"), tree.grants("r1"), tree.state("r1", "global_motion"),
                  tree.param_events("r1", "planner"), tree.operator("alice", "c1"),
                  tree.from_user("r1", "alice", "lights"),
                  tree.from_user("r1", "alice", "nav/goal"), tree.from_user("r1", "alice", Verb.CALL.value),
                  tree.to_user("r1", "alice", "error/x"), tree.from_user("r1", "alice", "reply/x"),
                  prefix, tree.robot_root("r1"), "elsewhere/r1/heartbeat", tree.heartbeat("r1") + "/x",
                  tree.state("r1", "a") + "//b", tree.operators_prefix() + "alice", ""]
        for verb in Verb:
            name = "x/y" if verb.named else ""
            build("userTopic", ["r1", "alice", verb.value, name], tree.user_topic("r1", "alice", verb, name))
            topics.append(tree.user_topic("r1", "alice", verb, name))
        parsed += [parsed_case(prefix, t) for t in topics]
    names = ["parameter_events/planner", "parameter_events/a/b", "parameter_events", "parameter_events/",
             "global_motion", "x/parameter_events/planner"]
    return {"built": built, "parsed": parsed,
            "paramEvents": [{"name": n, "expected": param_events_node(n)} for n in names]}


def test_the_dashboard_reads_bodies_messages_and_topics_as_python_does(tmp_path: Path) -> None:
    node = shutil.which("node")
    assert node, "node is needed (make install)"
    bodies, topics, messages = tmp_path / "bodies.json", tmp_path / "topics.json", tmp_path / "messages.json"
    bodies.write_bytes(orjson.dumps(cases()))
    topics.write_bytes(orjson.dumps(topic_cases()))
    messages.write_bytes(orjson.dumps(message_cases()))
    run = subprocess.run([node, "--test", str(ROOT / "tests" / "js")], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "ROSLINK_BODY_CASES": str(bodies), "ROSLINK_TOPIC_CASES": str(topics),
                              "ROSLINK_MESSAGE_CASES": str(messages)}, check=False)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    passed = re.search(r"^# pass (\d+)", run.stdout, re.M)
    assert passed and int(passed.group(1)) >= 20 and "# skipped 0" in run.stdout, run.stdout[-2000:]


def test_every_file_the_page_loads_is_served() -> None:
    """Each script, stylesheet and module index.html and the modules name is one of the server's routes."""
    from roslink_mqtt.dashboard.server import PageConfig, _routes

    page = (STATIC / "index.html").read_text()
    loaded = re.findall(r'<script (?:type="module" )?src="([^"]+)"', page) + \
        re.findall(r'<link rel="stylesheet" href="([^"]+)"', page)
    for module in STATIC.rglob("*.mjs"):
        here = module.parent.relative_to(STATIC)
        for target in re.findall(r'^import .*? from "([^"]+)";', module.read_text(), re.M | re.S):
            loaded.append(os.path.normpath(here / target))
    routes = _routes(Path("mqtt.min.js"), PageConfig())
    assert "main.mjs" in loaded and "vendor/uPlot.esm.js" in loaded and "views/fleet.mjs" in loaded, loaded
    assert [f for f in loaded if "/" + f not in routes] == []
