"""The one authorization rule: may this role use this verb on this name, and if not, why.

The bridge used to restate the rule in four places (commands in ``node.py``, service calls and offers in
``services.py``, advertisements in ``on_demand.py``), each worded its own way; the access report
(``access.py``) restated it a fifth time, and the SDK a sixth (refusing at once what the broker would drop).
Every check now asks :func:`refusal` — the bridge with the fleet file's role, the SDK with the role of the
robot's access report — so the rule and its wording change in one place. It imports nothing from ROS, so the
SDK and the unit tests use it without rclpy.

The rule mirrors the broker's ACL (``broker/acl.py``), which reads the same fleet file: an operator may do
everything; a viewer may only call services marked ``read_only``; a user without a grant may do nothing.

Every refusal reads ``user '<user>' may not <action> (<who may>): not an operator of <robot> (<standing>)``:
what was refused, the requirement, and why the user does not meet it, so a reader can tell a viewer from a
user whose grant was revoked.
"""

from __future__ import annotations

from .config import Role
from .topics import Verb

# what a viewer may do where the fleet file opens it to viewers (a read_only service, an action with viewers: true,
# reading parameters, setting those of a node with viewers_may_set, snapshots with snapshot.who: viewers; video
# streams are always open to viewers: read_only True). Declared with each verb (topics.py).
VIEWER_VERBS = frozenset(verb for verb in Verb if verb.open_to_viewers)


def allowed(role: Role | None, verb: Verb, *, read_only: bool = False) -> bool:
    """Whether ``role`` may use ``verb``; ``read_only``: the service is marked read-only, or the action is open
    to viewers (``viewers: true``); it means nothing for other verbs."""
    if role is Role.OPERATOR:
        return True
    return role is Role.VIEWER and verb in VIEWER_VERBS and read_only


def refusal(user: str, role: Role | None, verb: Verb, name: str, *, robot: str, read_only: bool = False) -> str | None:
    """None when ``user`` (holding ``role`` on ``robot``, None: no grant) may use ``verb`` on ``name``; else why not.

    ``name`` is what the verb acts on: the command's topic leaf (``cmd/twist``; a generic rule's input such as
    ``lights`` is a command too, verb :attr:`Verb.CMD`), the service, the on-demand topic. Verbs come from the
    topic grammar (:class:`roslink_mqtt.topics.Verb`). The wording is part of the protocol (docs/protocol.md
    quotes it; clients match on it).
    """
    if allowed(role, verb, read_only=read_only):
        return None
    if verb is Verb.WATCH and role is None:
        return f"user '{user}' may not {verb.refused(name, robot)} (any granted user may): no grant on {robot}"
    who_may = ("operators only; it is not read-only" if verb is Verb.CALL else
               "operators only; it is not open to viewers" if verb in VIEWER_VERBS else "operators only")
    standing = "a viewer" if role is Role.VIEWER else "no grant"
    return f"user '{user}' may not {verb.refused(name, robot)} ({who_may}): not an operator of {robot} ({standing})"
