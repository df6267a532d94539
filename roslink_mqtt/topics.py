"""The MQTT topic grammar (docs/protocol.md, "Topic tree"): the one place that builds and parses ROSLink topics.

Every other module builds topics, subscription filters and ACL patterns with
:class:`TopicTree` and reads incoming topics with :meth:`TopicTree.parse`, so a
new verb (actions, parameters…) is added here once and every peer agrees on it.
A test fails when another module splits or formats a topic string itself.

Builders refuse names that would change a topic's meaning: a robot called
``+`` or a user called ``a/b`` would let one principal's topic match
another's ACL. Filter builders take :data:`ANY` (``+``) where a level may vary.
Parsing returns None for topics outside the tree so callers can ignore foreign
traffic cheaply.

Grammar (``P`` is the prefix, ``roslink`` unless configured)::

    P/<robot>/heartbeat                      robot presence (retained)
    P/<robot>/grants                         who may use the robot (retained; admins write, the robot reads)
    P/<robot>/state/<name…>                  robot → everyone granted it
    P/<robot>/from/<user>/<verb>/<name…>     user → robot   (verbs sent by users)
    P/<robot>/from/<user>/<name…>            user → robot   (a generic rule's input: no verb)
    P/<robot>/to/<user>/<verb>[/<name…>]     robot → user   (verbs sent by robots)
    P/operators/<user>/<client id>           operator presence (retained)
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

DEFAULT_PREFIX = "roslink"
OPERATORS = "operators"
SEPARATOR = "/"
ANY = "+"  # one level of a subscription filter or ACL pattern
REST = "#"  # every level below, as the last level of a filter
SYS_TOPICS = "$SYS/#"  # the broker's own topics (outside the tree; admins may read them)
# The embedded broker's control topic (broker/admin.py; Mosquitto's is $CONTROL/dynamic-security/v1): admins only
FLEET_CONTROL = "$CONTROL/roslink/v1"
FLEET_CONTROL_RESPONSE = FLEET_CONTROL + "/response"
FLEET_CONTROL_FILTER = "$CONTROL/roslink/#"
# Mosquitto's dynamic-security plugin's (broker/export_dynsec.py, cli/fleet_dynsec.py)
DYNSEC_CONTROL = "$CONTROL/dynamic-security/v1"
DYNSEC_RESPONSE = DYNSEC_CONTROL + "/response"
DYNSEC_FILTER = "$CONTROL/dynamic-security/#"
PARAM_EVENTS = "parameter_events"  # state/parameter_events/<node>
# The levels after a robot's name (and the dashboard's topics.mjs, generated from these)
HEARTBEAT, STATE, FROM, TO = "heartbeat", "state", "from", "to"
GRANTS = "grants"  # P/<robot>/grants: the robot's users and roles, from the fleet's administrators


class TopicError(ValueError):
    """A name cannot be used in a topic (empty, or contains ``+``, ``#`` or ``/``)."""


def _levels(topic: str) -> list[str]:
    return topic.split(SEPARATOR)


def filter_levels(topic: str) -> tuple[str, ...]:
    """An MQTT topic or filter as its levels, for MQTT's wildcard matching (the broker's filter algebra: ACL
    patterns, the subscription index, the retained store). Not for reading the tree: :meth:`TopicTree.parse` is."""
    return tuple(topic.split(SEPARATOR))


def _join(*parts: str) -> str:
    """Levels (or already joined paths) back into one topic."""
    return SEPARATOR.join(parts)


def check_name(name: str, what: str = "name") -> str:
    """Validate one topic level (robot, user, client id, service name)."""
    if not isinstance(name, str) or not name:
        raise TopicError(f"{what} must be a non-empty string, got {name!r}")
    for bad in (ANY, REST, SEPARATOR, "\0"):
        if bad in name:
            raise TopicError(f"{what} {name!r} must not contain {bad!r}")
    if name.startswith("$"):
        raise TopicError(f"{what} {name!r} must not start with '$' (reserved for broker topics)")
    return name


def check_path(path: str, what: str = "name") -> str:
    """Validate a multi-level leaf such as ``cmd/twist`` (each level as :func:`check_name`)."""
    if not isinstance(path, str) or not path:
        raise TopicError(f"{what} must be a non-empty string, got {path!r}")
    for level in _levels(path):
        check_name(level, f"{what} level in {path!r}")
    return path


def check_filter_path(path: str, what: str = "filter") -> bool:
    """Validate a multi-level filter such as ``nav/+`` or ``#``; True if it has a wildcard.

    ``+`` and ``#`` are allowed as whole levels (MQTT wildcards), ``#`` only last, as the broker requires;
    every other level is checked as :func:`check_name`.
    """
    if not isinstance(path, str) or not path:
        raise TopicError(f"{what} must be a non-empty string, got {path!r}")
    parts = _levels(path)
    for i, level in enumerate(parts):
        if level == ANY or level == REST and i == len(parts) - 1:
            continue
        if REST in level or ANY in level:
            raise TopicError(f"'{path}': '+' and '#' must be whole levels, and '#' the last one (e.g. '#', 'nav/+')")
        check_name(level, f"{what} level in '{path}'")
    return ANY in parts or REST in parts


def _level_or_any(name: str, what: str) -> str:
    return ANY if name == ANY else check_name(name, what)


@dataclass(frozen=True, slots=True)
class VerbSpec:
    """One verb's declaration (the table below)."""

    meaning: str  # one line for docs/protocol.md's verb table
    by_user: bool  # sent by users (``from/<user>/…``), else by robots (``to/<user>/…``)
    refused: str = ""  # a user's verb: what a refusal says the user may not do
    viewers: bool = False  # a user's verb the fleet file may open to viewers

    @classmethod
    def user(cls, meaning: str, *, refused: str, viewers: bool = False) -> VerbSpec:
        return cls(meaning, True, refused, viewers)

    @classmethod
    def robot(cls, meaning: str) -> VerbSpec:
        return cls(meaning, False)


class Verb(Enum):
    """What a message under ``from/<user>/`` or ``to/<user>/`` is; its value is the topic level."""

    # sent by users (from/<user>/…)
    CMD = "cmd"  # a ROSLink command: cmd/<command>
    CALL = "call"  # call a ROS service: call/<service>
    PROVIDE = "provide"  # offer a service to ROS (retained; empty withdraws): provide/<service>
    RESPONSE = "response"  # a provider's answer: response/<service>
    ADVERTISE = "advertise"  # keep a generic rule's ROS publisher (retained; empty withdraws): advertise/<rule>
    GOAL = "goal"  # send a goal to a ROS action: goal/<action>
    CANCEL = "cancel"  # cancel one of your goals: cancel/<action>
    PARAM = "param"  # get, set, list or describe a ROS node's parameters: param/<node>
    LOG = "log"  # a log line for the robot's /rosout, from an SDK node: log/<node>
    DECLARE = "declare"  # an SDK node's parameters, held by the robot as ROS ones (retained; empty withdraws)
    PARAM_RESULT = "param_result"  # an SDK node's answer to a param_set: param_result/<node>
    PROVIDE_ACTION = "provide_action"  # serve a ROS action (retained; empty withdraws): provide_action/<action>
    ACTION_UPDATE = "action_update"  # a provider's accepted/rejected/feedback/end of a goal: action_update/<action>
    CONTROL = "control"  # claim, release or take over control of the robot: control/<claim|release|take_over>
    SNAPSHOT = "snapshot"  # ask for the last seconds of the robot's snapshot topics as MCAP: snapshot/<id>
    WATCH = "watch"  # keep a video stream coming (renewed while watching), or ask for a keyframe: watch/<stream>
    # sent by robots (to/<user>/…)
    REPLY = "reply"  # the answer to a call: reply/<service>
    REQUEST = "request"  # a ROS call for a provider: request/<service>
    ERROR = "error"  # refusals of what this user sent (no name)
    NOTICE = "notice"  # something this user sent was carried out, but changed (a clamped twist; no name)
    ACCESS = "access"  # what this user may do on the robot (retained, no name)
    GOAL_STATUS = "goal_status"  # a goal accepted, rejected or being canceled: goal_status/<action>
    FEEDBACK = "feedback"  # a goal's progress (newest wins): feedback/<action>
    RESULT = "result"  # a goal's end: result/<action>
    PARAM_REPLY = "param_reply"  # the answer to a param request: param_reply/<node>
    PARAM_SET = "param_set"  # a ROS client sets parameters of an SDK node: param_set/<node>
    ACTION_REQUEST = "action_request"  # a ROS goal or cancel for a provider: action_request/<action>
    SNAPSHOT_DATA = "snapshot_data"  # a chunk of the snapshot asked for: snapshot_data/<id>

    @property
    def meaning(self) -> str:
        """One line for docs/protocol.md's verb table (rendered from this enum)."""
        return _DECLARED[self].meaning

    @property
    def sent_by_user(self) -> bool:
        return _DECLARED[self].by_user

    @property
    def open_to_viewers(self) -> bool:
        """Whether the fleet file may open this verb to viewers (a read-only service, ``viewers: true``…)."""
        return _DECLARED[self].viewers

    def refused(self, name: str, robot: str) -> str:
        """What a refusal of this verb says the user may not do: ``call 'reset'`` (docs/protocol.md quotes it)."""
        return _DECLARED[self].refused.format(name=name, name_words=name.replace("_", " "), robot=robot)

    @property
    def named(self) -> bool:
        """Whether a name follows the verb (``call/reset``); ``error`` and ``access`` stand alone."""
        return self not in (Verb.ERROR, Verb.NOTICE, Verb.ACCESS)

    @property
    def retained_by_sender(self) -> bool:
        """Whether the sender publishes it retained: state that holds until withdrawn, not an order."""
        return self in (Verb.PROVIDE, Verb.ADVERTISE, Verb.ACCESS, Verb.DECLARE, Verb.PROVIDE_ACTION)


# Each verb, declared once: what it means (docs/protocol.md's verb table), who sends it, and for a user's verb what a
# refusal says the user may not do (``{name}``: the level after the verb, ``{name_words}`` the same with spaces,
# ``{robot}``) and whether the fleet file may open it to viewers (roslink_mqtt/authorize.py reads both).
_DECLARED: dict[Verb, VerbSpec] = {
    Verb.CMD: VerbSpec.user("a ROSLink command (`cmd/twist`) or a rule named `cmd/…`", refused="send '{name}'"),
    Verb.CALL: VerbSpec.user("call one of the robot's ROS services; answered on `reply/<service>`",
                             refused="call '{name}'", viewers=True),
    Verb.PROVIDE: VerbSpec.user("offer a service to ROS (an empty retained message withdraws)",
                                refused="provide services on {robot}"),
    Verb.RESPONSE: VerbSpec.user("a provider's answer to a `request/<service>`", refused="answer calls to '{name}'"),
    Verb.ADVERTISE: VerbSpec.user("keep a generic rule's ROS publisher while you are present (empty withdraws)",
                                  refused="publish on '{name}'"),
    Verb.GOAL: VerbSpec.user("send a goal to one of the robot's ROS actions (your id names it)",
                             refused="send goals to '{name}'", viewers=True),
    Verb.CANCEL: VerbSpec.user("cancel one of your goals", refused="cancel goals of '{name}'", viewers=True),
    Verb.PARAM: VerbSpec.user("get, set, list or describe the parameters of one of the robot's ROS nodes",
                              refused="set parameters of '{name}'", viewers=True),
    Verb.LOG: VerbSpec.user("a log line of one of your programs, for the robot's `/rosout`",
                            refused="write the robot's /rosout (as node '{name}')"),
    Verb.DECLARE: VerbSpec.user("the parameters of one of your SDK nodes, held by the robot as a ROS node's "
                                "(empty withdraws)", refused="declare parameters on {robot} (as node '{name}')"),
    Verb.PARAM_RESULT: VerbSpec.user("your SDK node's answer to a `param_set/<node>`: accepted, or refused with a "
                                     "reason", refused="answer parameter changes of '{name}'"),
    Verb.PROVIDE_ACTION: VerbSpec.user("serve a ROS action from your program (an empty retained message withdraws)",
                                       refused="provide actions on {robot}"),
    Verb.ACTION_UPDATE: VerbSpec.user("your answer on a goal you serve: accepted/rejected, feedback, its end and "
                                      "result", refused="answer goals of '{name}'"),
    Verb.CONTROL: VerbSpec.user("claim, release or take over control of the robot (`control/claim`, "
                                "`control/release`, `control/take_over`); `state/control` says who holds it",
                                refused="{name_words} control of {robot}"),
    Verb.SNAPSHOT: VerbSpec.user("ask for the last seconds of the robot's snapshot topics (ROS messages as MCAP); "
                                 "your id names it", refused="ask {robot} for snapshots", viewers=True),
    Verb.WATCH: VerbSpec.user("watch one of the robot's video streams: renew it while you watch (a viewer may), "
                              "leave when done", refused="watch '{name}'", viewers=True),
    Verb.REPLY: VerbSpec.robot("the answer to your `call/<service>`"),
    Verb.REQUEST: VerbSpec.robot("a ROS node calls a service you provide"),
    Verb.ERROR: VerbSpec.robot("why something you sent was refused"),
    Verb.NOTICE: VerbSpec.robot("something you sent was carried out, but not as sent (a twist clamped to the "
                                "robot's limits)"),
    Verb.ACCESS: VerbSpec.robot("what the broker lets you do on this robot"),
    Verb.GOAL_STATUS: VerbSpec.robot("your goal was accepted, rejected, or is being canceled"),
    Verb.FEEDBACK: VerbSpec.robot("your goal's progress (rate-limited, newest wins)"),
    Verb.RESULT: VerbSpec.robot("your goal ended: succeeded, aborted, canceled or timed out, with the ROS result"),
    Verb.PARAM_REPLY: VerbSpec.robot("the answer to your `param/<node>` request"),
    Verb.PARAM_SET: VerbSpec.robot("a ROS client sets parameters of your SDK node; answer on `param_result/<node>`"),
    Verb.ACTION_REQUEST: VerbSpec.robot("a ROS client sent a goal to (or canceled one of) an action you serve"),
    Verb.SNAPSHOT_DATA: VerbSpec.robot("a chunk of the snapshot you asked for (a JSON header line, then its bytes)"),
}

USER_VERBS = frozenset(verb for verb, spec in _DECLARED.items() if spec.by_user)
ROBOT_VERBS = frozenset(Verb) - USER_VERBS
# First levels an mqtt_to_ros rule may not use: the verbs with their own meaning (``cmd/`` is how rules are named).
RESERVED_RULE_LEVELS = tuple(sorted(v.value for v in USER_VERBS if v is not Verb.CMD)) + (STATE,)
# State names the bridge writes itself (acknowledgements, the robot's description, its uplink report, who holds
# control, a starting bridge's claim): no rule may.
BRIDGE_STATE_NAMES = ("ack", "description", "link", "control", "bridge")


def split_leaf(leaf: str, *, sent_by_user: bool = True) -> tuple[Verb | None, str]:
    """``cmd/twist`` → (CMD, ``twist``); a leaf without a verb of that direction → (None, leaf).

    A verb that needs a name but has none (``call``), or has one it must not
    (``error/x``), is no verb: the leaf is then read as a generic rule's name,
    which the robot answers with "no mapping".
    """
    head, _, rest = leaf.partition(SEPARATOR)
    try:
        verb = Verb(head)
    except ValueError:
        return None, leaf
    if verb.sent_by_user is not sent_by_user or bool(rest) is not verb.named:
        return None, leaf
    return verb, rest


def join_leaf(verb: Verb | None, name: str = "") -> str:
    """The inverse of :func:`split_leaf`: (CMD, ``twist``) → ``cmd/twist``; (None, ``lights``) → ``lights``."""
    if verb is None:
        return check_path(name, "name")
    if not verb.named:
        if name:
            raise TopicError(f"'{verb.value}' takes no name, got {name!r}")
        return verb.value
    return _join(verb.value, check_path(name, f"{verb.value} name"))


def _split_first(path: str) -> tuple[str, str]:
    head, _, rest = path.partition(SEPARATOR)
    return head, rest


def first_level(path: str) -> str:
    """``cmd/twist`` → ``cmd``: the level a rule's mqtt_topic starts with (the config checks reserve some)."""
    return _split_first(path)[0]


def state_leaf(name: str) -> str:
    """``global_motion`` → ``state/global_motion``: a ros_to_mqtt rule's mqtt_topic (relative to the robot)."""
    return _join(STATE, name)


def state_rule_name(path: str) -> str | None:
    """A rule's ``state/global_motion`` → ``global_motion``; None unless it is a state below ``state/``."""
    head, rest = _split_first(path)
    return rest if head == STATE and rest else None


VDA5050_INTERFACE = "uagv/v2"  # VDA 5050 §6.3: interface name and major version, the standard's own tree


def vda5050_topic(manufacturer: str, serial_number: str, leaf: str) -> str:
    """``uagv/v2/<manufacturer>/<serialNumber>/<leaf>``: a VDA 5050 vehicle's topic (roslink_mqtt/vda5050)."""
    return _join(VDA5050_INTERFACE, manufacturer, serial_number, leaf)


def sys_topic(*names: str) -> str:
    """A topic of the broker's own ``$SYS`` tree (outside the robots' tree): ``sys_topic("broker", "clients")``."""
    return _join("$SYS", *names)


def trimmed(name: str) -> str:
    """A path as a user may type it, without leading or trailing separators: ``/cmd/twist/`` → ``cmd/twist``."""
    return name.strip(SEPARATOR)


def state_name(name: str) -> str:
    """What a user means by a state name: ``state/global_motion``, ``/global_motion/`` → ``global_motion``."""
    name = name.strip(SEPARATOR)
    head, rest = _split_first(name)
    return rest if head == STATE else name


def grammar_words() -> dict[str, Any]:
    """The words of this grammar as data, for its second implementation: the dashboard's topics.mjs (generated
    into its protocol.mjs by :mod:`roslink_mqtt.dashboard.protocol_js`, checked case by case against this module)."""
    return {"separator": SEPARATOR, "any": ANY, "rest": REST, "operators": OPERATORS, "heartbeat": HEARTBEAT,
            "state": STATE, "from": FROM, "to": TO, "param_events": PARAM_EVENTS, "grants": GRANTS,
            "kinds": {k.name.lower(): k.value for k in Kind},
            "verbs": {v.value: {"named": v.named, "sent_by_user": v.sent_by_user} for v in Verb}}


def param_events_node(name: str) -> str | None:
    """A state name ``parameter_events/planner`` → ``planner``; None for any other state name."""
    head, rest = _split_first(name)
    return rest if head == PARAM_EVENTS and rest and SEPARATOR not in rest else None


def last_level(path: str) -> str:
    """``state/global_motion`` → ``global_motion``."""
    return path.rpartition(SEPARATOR)[2]


class Kind(Enum):
    HEARTBEAT = HEARTBEAT
    STATE = STATE
    FROM = FROM  # user → robot
    TO = TO  # robot → user
    OPERATOR = "operator"
    GRANTS = GRANTS  # admins → robot


@dataclass(frozen=True, slots=True)
class ParsedTopic:
    """A topic of the tree, read. ``verb`` is set for FROM/TO topics (None: a generic rule's input)."""

    kind: Kind
    robot: str | None = None
    user: str | None = None
    name: str | None = None  # state name; for FROM/TO the part after the verb (service, command, rule)
    client_id: str | None = None
    verb: Verb | None = None

    @property
    def leaf(self) -> str:
        """Everything after ``from/<user>/`` or ``to/<user>/`` (``cmd/twist``): what rules are keyed by."""
        if self.verb is None:
            return self.name or ""
        return _join(self.verb.value, self.name) if self.name else self.verb.value


class TopicTree:
    """Topic builder/parser for one prefix (``roslink`` unless configured)."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        self.prefix = check_path(prefix, "prefix")
        self._levels = len(_levels(prefix))

    # -- builders ---------------------------------------------------------
    def robot_root(self, robot: str) -> str:
        return _join(self.prefix, check_name(robot, "robot"))

    def heartbeat(self, robot: str) -> str:
        return _join(self.robot_root(robot), HEARTBEAT)

    def grants(self, robot: str) -> str:
        """Retained: who may use ``robot`` (protocol/grants.py), written by the fleet's administrators."""
        return _join(self.robot_root(robot), GRANTS)

    def state(self, robot: str, name: str) -> str:
        return _join(self.robot_root(robot), STATE, check_path(name, "state name"))

    def from_user(self, robot: str, user: str, leaf: str) -> str:
        """``leaf`` as :func:`join_leaf` makes it (``cmd/twist``, ``lights``)."""
        return _join(self.robot_root(robot), FROM, check_name(user, "user"), check_path(leaf))

    def to_user(self, robot: str, user: str, leaf: str) -> str:
        return _join(self.robot_root(robot), TO, check_name(user, "user"), check_path(leaf))

    def user_topic(self, robot: str, user: str, verb: Verb, name: str = "") -> str:
        """The topic of ``verb`` between ``user`` and ``robot``, in the direction the verb goes."""
        leaf = join_leaf(verb, name)
        return self.from_user(robot, user, leaf) if verb.sent_by_user else self.to_user(robot, user, leaf)

    def command(self, robot: str, user: str, command: str) -> str:
        return self.user_topic(robot, user, Verb.CMD, check_name(command, "command"))

    def call(self, robot: str, user: str, service: str) -> str:
        return self.user_topic(robot, user, Verb.CALL, check_path(service, "service"))

    def reply(self, robot: str, user: str, service: str) -> str:
        return self.user_topic(robot, user, Verb.REPLY, check_path(service, "service"))

    def provide(self, robot: str, user: str, service: str) -> str:
        return self.user_topic(robot, user, Verb.PROVIDE, check_path(service, "service"))

    def advertise(self, robot: str, user: str, name: str) -> str:
        """Retained: the user publishes on the generic rule ``name`` (its ROS publisher exists meanwhile)."""
        return self.user_topic(robot, user, Verb.ADVERTISE, check_path(name, "topic"))

    def request(self, robot: str, user: str, service: str) -> str:
        return self.user_topic(robot, user, Verb.REQUEST, check_path(service, "service"))

    def response(self, robot: str, user: str, service: str) -> str:
        return self.user_topic(robot, user, Verb.RESPONSE, check_path(service, "service"))

    def goal(self, robot: str, user: str, action: str) -> str:
        return self.user_topic(robot, user, Verb.GOAL, check_path(action, "action"))

    def cancel(self, robot: str, user: str, action: str) -> str:
        return self.user_topic(robot, user, Verb.CANCEL, check_path(action, "action"))

    def param(self, robot: str, user: str, node: str) -> str:
        return self.user_topic(robot, user, Verb.PARAM, check_name(node, "parameter node"))

    def log(self, robot: str, user: str, node: str) -> str:
        return self.user_topic(robot, user, Verb.LOG, check_name(node, "node name"))

    def declare(self, robot: str, user: str, node: str) -> str:
        """Retained: the parameters SDK node ``node`` of ``user`` declares (empty withdraws them)."""
        return self.user_topic(robot, user, Verb.DECLARE, check_name(node, "node name"))

    def param_set(self, robot: str, user: str, node: str) -> str:
        return self.user_topic(robot, user, Verb.PARAM_SET, check_name(node, "node name"))

    def param_result(self, robot: str, user: str, node: str) -> str:
        return self.user_topic(robot, user, Verb.PARAM_RESULT, check_name(node, "node name"))

    def param_events(self, robot: str, node: str) -> str:
        """Changes of ``node``'s parameters (from ROS ``/parameter_events``): a state topic, never retained."""
        return self.state(robot, _join(PARAM_EVENTS, check_name(node, "parameter node")))

    def error(self, robot: str, user: str) -> str:
        return self.user_topic(robot, user, Verb.ERROR)

    def notice(self, robot: str, user: str) -> str:
        return self.user_topic(robot, user, Verb.NOTICE)

    def access(self, robot: str, user: str) -> str:
        return self.user_topic(robot, user, Verb.ACCESS)

    def control(self, robot: str, user: str, op: str) -> str:
        """``from/<user>/control/<op>``: claim, release or take over control of ``robot``."""
        return self.user_topic(robot, user, Verb.CONTROL, check_name(op, "control request"))

    def operator(self, user: str, client_id: str) -> str:
        return _join(self.prefix, OPERATORS, check_name(user, "user"), check_name(client_id, "client id"))

    # -- subscription filters and ACL patterns (ANY = "+" allowed for robot/user) ------------
    def _root(self, robot: str) -> str:
        return _join(self.prefix, _level_or_any(robot, "robot"))

    def heartbeat_filter(self, robot: str = ANY) -> str:
        return _join(self._root(robot), HEARTBEAT)

    def grants_filter(self, robot: str = ANY) -> str:
        return _join(self._root(robot), GRANTS)

    def state_filter(self, robot: str = ANY, name: str = REST) -> str:
        """State topics of ``robot`` (every robot with ANY) whose name matches ``name`` (a filter: ``nav/+``)."""
        check_filter_path(name, "state name")
        return _join(self._root(robot), STATE, name)

    def from_user_filter(self, robot: str, user: str = ANY) -> str:
        """Everything ``user`` (every user with ANY) sends ``robot``: what a bridge subscribes to."""
        return _join(self._root(robot), FROM, _level_or_any(user, "user"), REST)

    def to_user_filter(self, robot: str, user: str = ANY) -> str:
        """Everything ``robot`` sends ``user``: replies, requests, errors, the access report."""
        return _join(self._root(robot), TO, _level_or_any(user, "user"), REST)

    def verb_filter(self, robot: str, user: str, verb: Verb) -> str:
        """Every ``verb`` message between ``user`` and ``robot`` (e.g. all of alice's replies)."""
        side = FROM if verb.sent_by_user else TO
        tail = (verb.value, REST) if verb.named else (verb.value,)
        return _join(self._root(robot), side, _level_or_any(user, "user"), *tail)

    def operators_filter(self, user: str, *, deep: bool = False) -> str:
        """Presence of every program of ``user`` (``deep``: any depth, as ACL patterns grant it)."""
        return _join(self.prefix, OPERATORS, _level_or_any(user, "user"), REST if deep else ANY)

    def operators_prefix(self) -> str:
        """The text every operator presence topic starts with (a cheap test on every PUBLISH)."""
        return _join(self.prefix, OPERATORS, "")

    def all_from_users(self, robot: str) -> str:
        return self.from_user_filter(robot)

    def operators_of(self, user: str) -> str:
        return self.operators_filter(user)

    def all_state(self, robot: str = ANY) -> str:
        return self.state_filter(robot)

    def all_heartbeats(self) -> str:
        return self.heartbeat_filter()

    # -- parsing -----------------------------------------------------------
    # -- names outside MQTT: what the Foxglove gateway calls a robot's services, parameters and inputs -------
    def gateway_name(self, robot: str, verb: Verb, name: str) -> str:
        """``<prefix>/<robot>/<verb>/<name>``: the topic tree's name for one of ``robot``'s services
        (``call/status``), parameters (``param/<node>/<name>``) or commands (``cmd/twist``), without the user
        level (the gateway is one user's)."""
        return _join(self.robot_root(robot), verb.value, name)

    def gateway_param(self, robot: str, node: str, name: str) -> str:
        """``<prefix>/<robot>/param/<node>/<name>``: one parameter of a node the robot exposes."""
        return self.gateway_name(robot, Verb.PARAM, _join(node, name))

    def parse_gateway_param(self, text: str) -> tuple[str, str, str] | None:
        """``(robot, node, name)`` of a :meth:`gateway_param`; None for anything else."""
        parsed = self.parse_gateway_name(text)
        if parsed is None or parsed[1] is not Verb.PARAM:
            return None
        node, name = _split_first(parsed[2])
        return (parsed[0], node, name) if name else None

    def parse_gateway_name(self, text: str) -> tuple[str, Verb, str] | None:
        """``(robot, verb, name)`` of a :meth:`gateway_name`; None for anything else."""
        parts = _levels(text)
        if _join(*parts[: self._levels]) != self.prefix:
            return None
        rest = parts[self._levels:]
        if len(rest) < 3 or any(not level for level in rest):
            return None
        try:
            verb = Verb(rest[1])
        except ValueError:
            return None
        return rest[0], verb, _join(*rest[2:])

    def parse(self, topic: str) -> ParsedTopic | None:
        """Classify a concrete topic; None if it is not part of the tree."""
        parts = _levels(topic)
        if _join(*parts[: self._levels]) != self.prefix:
            return None
        rest = parts[self._levels:]
        if not rest or any(not level for level in rest):
            return None
        if rest[0] == OPERATORS:
            if len(rest) != 3:
                return None
            return ParsedTopic(Kind.OPERATOR, user=rest[1], client_id=rest[2])
        robot = rest[0]
        if len(rest) == 2 and rest[1] == HEARTBEAT:
            return ParsedTopic(Kind.HEARTBEAT, robot=robot)
        if len(rest) == 2 and rest[1] == GRANTS:
            return ParsedTopic(Kind.GRANTS, robot=robot)
        if len(rest) >= 3 and rest[1] == STATE:
            return ParsedTopic(Kind.STATE, robot=robot, name=_join(*rest[2:]))
        if len(rest) >= 4 and rest[1] in (FROM, TO):
            kind = Kind.FROM if rest[1] == FROM else Kind.TO
            verb, name = split_leaf(_join(*rest[3:]), sent_by_user=kind is Kind.FROM)
            return ParsedTopic(kind, robot=robot, user=rest[2], name=name, verb=verb)
        return None
