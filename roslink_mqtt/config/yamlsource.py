"""YAML loading that remembers where every value came from.

PyYAML's ``safe_load`` forgets line numbers, and a fleet file is edited by
hand: an error that names the line and key path saves the operator a hunt.
We compose the node graph, then build plain Python values alongside a map
from key path to line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import yaml

Path = tuple[str | int, ...]


class ConfigError(ValueError):
    """An invalid fleet file; the message reads ``file:line key.path: what is wrong``."""

    def __init__(self, message: str, *, file: str = "", line: int | None = None, path: str = "") -> None:
        self.file, self.line, self.path, self.reason = file, line, path, message
        where = file + (f":{line}" if line else "")
        prefix = " ".join(p for p in (where, path) if p)
        super().__init__(f"{prefix}: {message}" if prefix else message)


def format_path(path: Path) -> str:
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + part
    return out


@dataclass
class Source:
    """Parsed YAML plus the line (1-based) of every value, by path."""

    file: str
    data: Any
    lines: dict[Path, int] = field(default_factory=dict)

    def line_of(self, path: Path) -> int | None:
        """Line of ``path``, or of its nearest ancestor that exists."""
        while True:
            if path in self.lines:
                return self.lines[path]
            if not path:
                return None
            path = path[:-1]

    def error(self, path: Path, message: str) -> ConfigError:
        return ConfigError(message, file=self.file, line=self.line_of(path), path=format_path(path))


def load_yaml(text: str, file: str = "<string>") -> Source:
    """Parse ``text``; syntax errors and duplicate keys become ConfigError with a line."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as err:
        mark = err.context_mark or err.problem_mark  # where the broken construct starts
        line = mark.line + 1 if mark else None
        raise ConfigError(f"invalid YAML: {err.problem or err}", file=file, line=line) from None
    except yaml.YAMLError as err:
        raise ConfigError(f"invalid YAML: {err}", file=file) from None
    source = Source(file, None)
    if node is None:
        source.data = {}
        return source
    constructor = yaml.SafeLoader("")
    try:
        source.data = _Builder(source, constructor).build(node, ())
    finally:
        constructor.dispose()
    return source


class _Builder:
    def __init__(self, source: Source, constructor: yaml.SafeLoader) -> None:
        self.source, self.constructor = source, constructor

    def build(self, node: yaml.Node, path: Path, line: int | None = None) -> Any:
        """``line`` is the key's line for mapping values: ``turtle1:`` names the robot, not its first key."""
        source = self.source
        source.lines[path] = line or node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Any] = {}
            for key_node, value_node in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    raise source.error(path, "YAML merge keys (<<) are not supported; write the keys out")
                key = self.scalar(key_node)
                if not isinstance(key, (str, int)) or isinstance(key, bool):
                    raise ConfigError(f"mapping keys must be strings, got {key!r}", file=source.file,
                                      line=key_node.start_mark.line + 1, path=format_path(path))
                key = str(key)
                if key in out:
                    raise ConfigError(f"duplicate key '{key}'", file=source.file,
                                      line=key_node.start_mark.line + 1, path=format_path(path))
                out[key] = self.build(value_node, path + (key,), key_node.start_mark.line + 1)
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self.build(item, path + (i,)) for i, item in enumerate(node.value)]
        return self.scalar(node)

    def scalar(self, node: yaml.Node) -> Any:
        if not isinstance(node, yaml.ScalarNode):
            raise ConfigError("mapping keys must be plain values", file=self.source.file,
                              line=node.start_mark.line + 1)
        try:
            return self.constructor.construct_object(node, deep=True)
        except yaml.YAMLError as err:
            raise ConfigError(f"invalid value: {err}", file=self.source.file,
                              line=node.start_mark.line + 1) from None
