"""Changes to robots.yaml that keep its comments and layout: ``roslink-mqtt fleet user|grant|revoke|robot``.

A fleet file is written by people: comments say whose password is whose, anchors share a robot's rules. Loading
it with PyYAML and dumping it back would drop all of that, so these edits go through ruamel.yaml's round trip,
which changes only the nodes touched. Every edit is checked by the fleet loader before the file is replaced (a
temporary file and a rename, in the same directory, with the old file's mode), so a change that would make the
broker refuse the file is not written at all.
"""

from __future__ import annotations

import copy
import difflib
import io
import os
import tempfile
from pathlib import Path
from typing import Any

from ruamel.yaml import YAML
from ruamel.yaml.comments import CommentedMap, CommentedSeq

from .loader import parse_fleet
from .model import Role
from .yamlsource import ConfigError


class FleetEditError(ValueError):
    """An edit that cannot be made (an unknown robot, a user who already exists…): the reason, for the user."""


class FleetEdit:
    """robots.yaml, loaded for a round trip; the methods change it, :meth:`save` checks and writes it."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._yaml = YAML()
        self._yaml.preserve_quotes = True
        self._yaml.indent(mapping=2, sequence=4, offset=2)  # `key:` then `  - item`, as the demo fleet writes
        self._yaml.width = 4096  # never fold: a password hash (~170 characters) stays on its `password:` line
        try:
            self._original = self.path.read_text(encoding="utf-8")
        except OSError as err:
            raise FleetEditError(f"cannot read {self.path}: {err.strerror or err}") from None
        self.data: CommentedMap = self._yaml.load(self._original)
        self._original_dump = self._dump(self.data)  # the round trip before any edit (see text())
        if not isinstance(self.data, dict) or not isinstance(self.data.get("robots"), dict):
            raise FleetEditError(f"{self.path} is not a fleet file (no robots)")

    # -- reading --------------------------------------------------------------------------------------------
    def _robot(self, name: str) -> Any:
        robots = self.data["robots"]
        if name not in robots:
            raise FleetEditError(f"no robot '{name}' in {self.path} (robots: {', '.join(robots) or 'none'})")
        return robots[name]

    def _users(self) -> Any:
        if self.data.get("users") is None:
            self.data["users"] = CommentedMap()
        return self.data["users"]

    def _user(self, name: str) -> Any:
        users = self._users()
        if name not in users:
            raise FleetEditError(f"no user '{name}' in {self.path} (users: {', '.join(users) or 'none'})")
        return users[name]

    # -- edits ----------------------------------------------------------------------------------------------
    def add_user(self, name: str, password_hash: str, *, admin: bool = False) -> None:
        users = self._users()
        if name in users:
            raise FleetEditError(f"user '{name}' is already in {self.path}")
        if name in self.data["robots"]:
            raise FleetEditError(f"'{name}' is a robot's login in {self.path}: a user needs a name of its own")
        entry = CommentedMap()
        entry["password"] = password_hash
        if admin:
            entry["admin"] = True
        else:
            entry["grants"] = CommentedSeq()
        users[name] = entry

    def remove_user(self, name: str) -> None:
        self._user(name)
        del self._users()[name]

    def grant(self, user: str, robot: str, role: Role) -> bool:
        """Give ``user`` ``role`` on ``robot`` (by the robot's key); False when it already had exactly that."""
        key = self._robot(robot)["key"]
        entry = self._user(user)
        if entry.get("grants") is None:
            entry["grants"] = CommentedSeq()
        grants = entry["grants"]
        for grant in grants:
            if grant.get("key") == key:
                if grant["role"] == role.value:  # a loaded fleet file has a role in every grant
                    return False
                grant["role"] = role.value
                return True
        new = CommentedMap([("key", key), ("role", role.value)])
        new.fa.set_flow_style()  # `- {key: …, role: …}`, as the demo fleet writes grants
        grants.append(new)
        return True

    def revoke(self, user: str, robot: str) -> None:
        key = self._robot(robot)["key"]
        grants = self._user(user).get("grants") or []
        kept = [g for g in grants if g.get("key") != key]
        if len(kept) == len(grants):
            raise FleetEditError(f"user '{user}' has no grant on {robot}")
        grants[:] = kept

    def add_robot(self, name: str, *, key: str, password_hash: str, like: str | None = None,
                  broker_url: str | None = None) -> int:
        """A new robot with the next free system_id (returned), its own key and password hash; ``like``: the
        rules, services, actions, parameters, snapshot, type and bridge settings of that robot (shared as YAML
        aliases where the author anchored them, so the two stay alike; copied otherwise), else none.
        ``broker_url``: where its bridge dials (``bridge.broker``)."""
        robots = self.data["robots"]
        if name in robots:
            raise FleetEditError(f"robot '{name}' is already in {self.path}")
        if name in self._users():
            raise FleetEditError(f"'{name}' is a user's login in {self.path}: a robot needs a name of its own")
        used = {int(r["system_id"]) for r in robots.values() if isinstance(r, dict) and "system_id" in r}
        system_id = next(i for i in range(1, 65536) if i not in used)
        entry = CommentedMap([("system_id", system_id), ("key", key), ("password", password_hash)])
        if like is not None:
            template = self._robot(like)
            for field, value in template.items():
                if field in entry:
                    continue
                anchored = getattr(getattr(value, "anchor", None), "value", None) is not None
                # an anchored node is shared (dumped as an alias of the template's); another is copied: an alias
                # would make ruamel invent an anchor (&id001) on the author's own line
                entry[field] = value if anchored or not isinstance(value, (dict, list)) else copy.deepcopy(value)
        if broker_url is not None:
            # its own copy (the template's with a broker of its own), not an alias with a changed key
            bridge = copy.deepcopy(entry["bridge"]) if isinstance(entry.get("bridge"), dict) else CommentedMap()
            bridge["broker"] = broker_url
            entry["bridge"] = bridge
        robots[name] = entry
        return system_id

    def rotate_password(self, robot: str, password_hash: str) -> None:
        """A new password for ``robot``, its current one kept as ``previous_password``: the broker accepts both
        until :meth:`finish_rotation`, so the robot's bridge moves over without being refused."""
        entry = self._robot(robot)
        if "previous_password" in entry:
            raise FleetEditError(f"{robot} is already moving to a new password: finish that first "
                                 f"(`roslink-mqtt fleet robot rotate {robot} --finish`)")
        entry["previous_password"] = entry["password"]
        entry["password"] = password_hash

    def finish_rotation(self, robot: str) -> None:
        """Stop accepting ``robot``'s previous password."""
        entry = self._robot(robot)
        if "previous_password" not in entry:
            raise FleetEditError(f"{robot} has no previous password to drop")
        del entry["previous_password"]

    # -- writing --------------------------------------------------------------------------------------------
    def _dump(self, data: Any) -> str:
        out = io.StringIO()
        self._yaml.dump(data, out)
        return out.getvalue()

    def text(self) -> str:
        """The edited file: the author's text with only the edited lines changed, where that can be told apart.

        ruamel keeps comments, anchors and block layout, but re-wraps long flow mappings (`- {a: 1, …}` written
        over two lines). So the edit is found as the difference between the round trip of the file as read and
        of the edited data, and applied to the author's own lines when every line it touches came through the
        round trip unchanged; otherwise the round trip is the result (its content is the same)."""
        edited = self._dump(self.data).splitlines(keepends=True)
        before = self._original_dump.splitlines(keepends=True)
        author = self._original.splitlines(keepends=True)
        same = {}  # line of the round trip as read → the same line of the author's text
        for block in difflib.SequenceMatcher(None, before, author, autojunk=False).get_matching_blocks():
            same.update({block.a + i: block.b + i for i in range(block.size)})
        out, taken = [], 0  # author's lines copied so far
        for tag, i1, i2, j1, j2 in difflib.SequenceMatcher(None, before, edited, autojunk=False).get_opcodes():
            if tag == "equal":
                continue
            # the author's lines around the hunk must be the round trip's, or the hunk cannot be placed
            start = same.get(i1 - 1, -2) + 1 if i1 else 0
            if (i1 and i1 - 1 not in same) or start < taken or any(same.get(k) != start + k - i1
                                                                    for k in range(i1, i2)):
                return "".join(edited)
            out += author[taken:start]
            out += edited[j1:j2]
            taken = start + (i2 - i1)
        return "".join(out + author[taken:])

    def save(self) -> None:
        """Check the edited fleet as the broker would, then replace the file (same directory, same mode)."""
        text = self.text()
        try:
            parse_fleet(text, str(self.path))
        except ConfigError as err:
            raise FleetEditError(f"not written, the fleet would be invalid: {err}") from None
        mode = self.path.stat().st_mode & 0o7777
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                f.write(text)
            os.chmod(tmp, mode)
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
