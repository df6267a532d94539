"""Write the SDK's message classes into roslink_mqtt/client/messages.py from the protocol's SPECS.

    .venv/bin/python -m roslink_mqtt.client.message_codegen          # rewrite the generated block
    .venv/bin/python -m roslink_mqtt.client.message_codegen --check  # exit 1 when the block is stale

Why generated source rather than classes built at import time: type checkers
and IDEs read source, so ``GlobalMotion(x=…)`` is checked and completed only
when the class is written out. Why generated at all: the schema
(roslink_mqtt/protocol/messages.py) stays the one place a field is declared;
tests/unit/test_sdk_message_types.py fails when the block and the schema differ.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..protocol import SPECS, FieldKind, MessageSpec
from .errors import InvalidArgument

TARGET = Path(__file__).with_name("messages.py")
BEGIN = "# BEGIN GENERATED: message classes (python -m roslink_mqtt.client.message_codegen)\n"
END = "# END GENERATED: message classes\n"

_ANNOTATIONS: dict[FieldKind, str] = {
    FieldKind.INT: "int", FieldKind.FLOAT: "float", FieldKind.STR: "str", FieldKind.BOOL: "bool",
    FieldKind.FLOAT_LIST: "tuple[float, ...]", FieldKind.RANGE_LIST: "tuple[float | None, ...]",
    FieldKind.INT_LIST: "tuple[int, ...]", FieldKind.BASE64: "bytes",
}


def class_name(spec: MessageSpec) -> str:
    """``global_motion`` → ``GlobalMotion``."""
    return "".join(part.capitalize() for part in spec.name.split("_"))


def _docstring(text: str) -> str:
    if '"""' in text or "\\" in text:
        raise InvalidArgument(f"cannot write {text!r} as a plain docstring")
    return f'"""{text}"""'


def _render_class(spec: MessageSpec) -> str:
    doc = f"ROSLink message {int(spec.message_id)} ({spec.name}). {spec.doc}".strip()
    lines = [
        "@dataclass(frozen=True, slots=True)",
        f"class {class_name(spec)}(RoslinkMessage):",
        f"    {_docstring(doc)}",
        "",
        f"    SPEC: ClassVar[MessageSpec] = SPECS_BY_NAME[{spec.name!r}]",
        f"    MESSAGE_ID: ClassVar[MessageId] = MessageId.{spec.message_id.name}",
        f"    NAME: ClassVar[str] = {spec.name!r}",
    ]
    if spec.fields:
        lines.append("")
    # required fields first, as dataclasses need (the order positional construction uses)
    for f in sorted(spec.fields, key=lambda f: not f.required):
        options = [] if f.required else [f"default={tuple(f.default) if isinstance(f.default, list) else f.default!r}"]
        options.append(f"metadata={{'doc': {f.doc!r}}}")
        line = f"    {f.name}: {_ANNOTATIONS[f.kind]} = dataclasses.field({', '.join(options)})"
        lines.append(line if len(line) <= 120 else f"{line}  # noqa: E501")
    return "\n".join(lines) + "\n"


def render() -> str:
    """The generated block, markers included."""
    classes = "\n\n".join(_render_class(spec) for spec in SPECS)
    table = "".join(f"    {spec.name!r}: {class_name(spec)},\n" for spec in SPECS)
    return (f"{BEGIN}\n\n{classes}\n\n"
            f"MESSAGE_CLASSES: dict[str, type[RoslinkMessage]] = {{\n{table}}}\n{END}")


def current(text: str) -> str:
    """The generated block as it stands in ``text`` (markers included)."""
    start, end = text.index(BEGIN), text.index(END) + len(END)
    return text[start:end]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if messages.py differs from the schema")
    args = parser.parse_args(argv)
    text = TARGET.read_text()
    block = render()
    if current(text) == block:
        return 0
    if args.check:
        print(f"{TARGET} is stale: run python -m roslink_mqtt.client.message_codegen", file=sys.stderr)
        return 1
    TARGET.write_text(text.replace(current(text), block))
    return 0


if __name__ == "__main__":
    sys.exit(main())
