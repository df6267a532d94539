"""What each granted user may do on this robot, published so that clients can refuse what the broker would drop.

A broker drops a PUBLISH its ACL denies without a word (MQTT 3.1.1 has no
negative PUBACK; Mosquitto even acknowledges it), so a viewer's command or a
call to a service it may not call would simply vanish and the bridge would never
hear of it. The broker's ACL and this bridge read the same fleet file, so the
bridge can tell each user what the broker allows them: a retained
:class:`~roslink_mqtt.protocol.control.AccessReport` on ``to/<user>/access``,
readable by that user alone (the ACL every broker already applies to ``to/<user>/#``).
"""

from __future__ import annotations

from ...authorize import allowed
from ...config import Fleet, Role
from ...protocol.control import AccessReport
from ...topics import TopicTree, Verb


def access_reports(fleet: Fleet, robot: str, topics: TopicTree) -> dict[str, bytes]:
    """``{topic: retained body}`` for every user granted ``robot`` (admins count as operators)."""
    services, actions = fleet.robots[robot].services, fleet.robots[robot].actions
    out: dict[str, bytes] = {}
    for user, role in sorted(fleet.users_of(robot).items()):
        callable_ = tuple(s.name for s in services if allowed(role, Verb.CALL, read_only=s.read_only))
        goals = tuple(a.name for a in actions if allowed(role, Verb.GOAL, read_only=a.viewers))
        estop = bool(fleet.robots[robot].estop_inputs) and (role is Role.OPERATOR or
                                                            fleet.robots[robot].estop == "viewers")
        kept = fleet.robots[robot].snapshot
        snapshot = kept is not None and allowed(role, Verb.SNAPSHOT, read_only=kept.who == "viewers")
        report = AccessReport("operator" if role is Role.OPERATOR else "viewer", callable_, goals, estop, snapshot)
        out[topics.access(robot, user)] = report.to_json()
    return out


def cleared_reports(before: Fleet, after: Fleet, robot: str, topics: TopicTree) -> list[str]:
    """Access topics of users who lost ``robot`` in a reload: their retained report must be cleared."""
    gone = set(before.users_of(robot)) - set(after.users_of(robot))
    return [topics.access(robot, user) for user in sorted(gone)]
