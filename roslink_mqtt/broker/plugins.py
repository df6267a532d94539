"""amqtt plugins: fleet authentication, the ROSLink topic ACL and a small ``$SYS`` publisher.

They use amqtt's public plugin API (0.12.1): the broker builds each plugin's inner
``Config`` dataclass from the ``plugins`` section of its config dict with dacite, and
fields typed ``Any`` pass Python objects through untouched. That is how the plugins
share one :class:`~roslink_mqtt.broker.acl.LiveFleet` with the runner, which swaps the
fleet on SIGHUP: no copy, so a reload reaches the plugins at once.

The built-in ``amqtt.plugins.topic_checking.TopicAccessControlListPlugin`` is not used: it
ignores subscribe/receive rules and an empty publish list allows everything.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass
from typing import Any

from amqtt.broker import BrokerContext
from amqtt.contexts import Action
from amqtt.mqtt.connack import SERVER_UNAVAILABLE
from amqtt.plugins.base import BaseAuthPlugin, BasePlugin, BaseTopicPlugin
from amqtt.session import Session

from .. import __version__
from ..config import verify_password
from ..config.passwords import DEFAULT_ITERATIONS, VerifiedLogins
from ..topics import sys_topic
from .acl import DecisionCache, LiveFleet
from .admission import Admission
from .hardened import AMQTT_VERSION, ATTR_DENY_CODE, ATTR_DENY_REASON, describe_session
from .hashing import HashPool
from .ratelimit import REFUSE, LoginThrottle

log = logging.getLogger("roslink_mqtt.broker")

ATTR_ACL_CACHE = "roslink.acl"
# Verified against when the login is unknown, so a wrong name costs as long as a wrong password (of a hash made
# with the default iteration count).
_DUMMY_HASH = f"$7${DEFAULT_ITERATIONS}$AAAAAAAAAAAAAAAA$" + "A" * 86 + "=="


def plugin_path(cls: type) -> str:
    """The dotted path amqtt's ``plugins`` config expects."""
    return f"{cls.__module__}.{cls.__qualname__}"


class FleetAuthPlugin(BaseAuthPlugin):
    """Every connection presents a robot or user login from robots.yaml; anonymous is refused.

    Passwords are checked against the Mosquitto ``$7$`` PBKDF2 hashes on one worker thread with a bounded queue
    (:class:`~roslink_mqtt.broker.hashing.HashPool`: a flood of guesses takes at most one core, and a check that
    would wait too long is refused as "server unavailable"), once per login: a verified one is remembered
    (:class:`~roslink_mqtt.config.passwords.VerifiedLogins`), so reconnects cost a keyed SHA-256. Failed attempts
    feed the :class:`~roslink_mqtt.broker.ratelimit.LoginThrottle` (per login, per address, per pair).
    """

    @dataclass
    class Config:
        fleet: Any = None  # LiveFleet
        throttle: Any = None  # LoginThrottle | None

    def __init__(self, context: BrokerContext) -> None:
        super().__init__(context)
        self.verified = VerifiedLogins()  # a login's PBKDF2 once, not on every reconnect
        self.hashing = HashPool()  # the slow checks: one thread, a bounded wait (broker/hashing.py)
        self.admission = Admission()  # logins waiting for a place among those being checked (broker/admission.py)

    async def authenticate(self, *, session: Session) -> bool | None:
        live: LiveFleet = self.config.fleet
        throttle: LoginThrottle | None = self.config.throttle
        address = session.remote_address or "?"
        username = session.username
        admitted: tuple[tuple[str, str], ...] = ()
        if throttle is not None:
            slot = await self.admission.begin(throttle, address, username or "")  # others of it in check: wait
            if slot is None:
                session.attributes[ATTR_DENY_REASON] = "too many logins in progress for this login or address"
                return False
            admitted = slot
        try:
            return await self._check(session, live, throttle, address)
        finally:
            if throttle is not None:
                self.admission.end(throttle, admitted)  # the oldest waiting for each place freed goes next

    async def _check(self, session: Session, live: LiveFleet, throttle: LoginThrottle | None, address: str) -> bool:
        username, password = session.username, session.password
        if throttle is not None:
            wait = throttle.reserve(address, username or "")
            if wait == REFUSE:
                session.attributes[ATTR_DENY_REASON] = "too many failed logins for this login or address; try later"
                return False
            if wait > 0:
                await asyncio.sleep(wait)
        reason = None
        if not username:
            reason = "anonymous connections are not allowed"
        elif password is None:
            reason = "no password"
        else:
            accepted = live.fleet.accepted_hashes(username)
            # a login verified before costs a keyed SHA-256, here; any other waits for the one hashing thread, or,
            # when that queue is already longer than HashPool.max_wait, is refused as "server unavailable" at once
            ok = any(self.verified.remembered(password, stored) for stored in accepted)
            if not ok:
                # under load, checks that may succeed go first: a login that exists, from an address and for a
                # login with no recent failures (a guesser's made-up names and failing addresses wait for an idle
                # thread); a login that does not exist still costs a full hash when checked (no timing oracle)
                failing = throttle is not None and not throttle.is_known_good(address, username) and \
                    (throttle.failures(address) > 0 or throttle.login_failures(username) > 0)
                suspect = not accepted or failing
                if self.hashing.busy(suspect):
                    session.attributes[ATTR_DENY_REASON] = (
                        f"the broker is checking many other passwords ({self.hashing.waiting} waiting, about "
                        f"{self.hashing.expected_wait():.1f} s): try again")
                    session.attributes[ATTR_DENY_CODE] = SERVER_UNAVAILABLE
                    return False  # not the user's failure: the throttle does not count it
                ok = await self.hashing.run(lambda: self._verify(password, accepted))
            if not accepted:
                reason = "unknown login"
            elif not ok:
                reason = "wrong password"
        if reason is not None:
            session.attributes[ATTR_DENY_REASON] = reason
            if throttle is not None:
                throttle.failed(address, username or "")
            return False
        if throttle is not None:
            throttle.succeeded(address, username)
        return True


    def _verify(self, password: str, accepted: tuple[str, ...]) -> bool:
        """Whether ``password`` matches one of ``accepted`` (a robot's new and previous hash while it rotates); an
        unknown login costs a full hash too, so a wrong name answers no faster than a wrong password."""
        if not accepted:
            verify_password(password, _DUMMY_HASH)
            return False
        return any(self.verified.verify(password, stored) for stored in accepted)


class FleetAclPlugin(BaseTopicPlugin):
    """The access rules of broker/acl.py on PUBLISH, SUBSCRIBE and RECEIVE, cached per session.

    The verdict for (topic, action) is computed once per session from the current
    :class:`~roslink_mqtt.broker.acl.FleetAcl` and kept in ``session.attributes``; after a
    reload the cache no longer matches the new FleetAcl and is rebuilt, so a revoked grant
    denies the very next delivery. Denied PUBLISH/SUBSCRIBE are logged once per session and
    topic (on the cache miss); denied RECEIVE is normal for wildcard subscribers and only
    logged at DEBUG.
    """

    @dataclass
    class Config:
        fleet: Any = None  # LiveFleet
        cache_bytes: int = 256 * 1024  # per session (BrokerLimits.acl_cache_bytes)

    async def topic_filtering(self, *, session: Session | None = None, topic: str | None = None,
                              action: Action | None = None) -> bool | None:
        if session is None or topic is None or action is None:
            return False
        acl = self.config.fleet.acl
        cache: DecisionCache | None = session.attributes.get(ATTR_ACL_CACHE)
        if cache is None or not cache.valid_for(acl, session.username):
            cache = session.attributes[ATTR_ACL_CACHE] = DecisionCache(
                acl, session.username, limit_bytes=self.config.cache_bytes)
        verdict = cache.lookup(topic, action)
        if verdict is None:
            verdict = cache.decide(topic, action)
            # during CONNECT (will-topic check) the broker logs the refusal itself, in one line
            if not verdict and session.transitions.state == "connected":
                level = logging.DEBUG if action == Action.RECEIVE else logging.INFO
                log.log(level, "deny %s %s topic=%r", action.value, describe_session(session), topic)
        return verdict


class SysInfoPlugin(BasePlugin[BrokerContext]):
    """A few ``$SYS/broker/...`` topics, retained, readable by admins only.

    amqtt's own ``BrokerSysPlugin`` hooks every packet sent and received (a Task per
    packet); this one only samples the session table every ``interval`` seconds.
    """

    @dataclass
    class Config:
        interval: float = 10.0  # s; 0 publishes only the version

    _task: asyncio.Task[None] | None = None
    _started = 0.0

    async def on_broker_post_start(self) -> None:
        self._started = time.monotonic()
        await self._set("version", f"roslink-mqtt {__version__} (amqtt {AMQTT_VERSION})")
        if self.config.interval > 0:
            self._task = asyncio.create_task(self._run())

    async def on_broker_pre_shutdown(self) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)

    async def _set(self, name: str, value: str) -> None:
        topic, data = sys_topic("broker", name), value.encode()
        await self.context.retain_message(topic, data, 0)
        await self.context.broadcast_message(topic, data, 0)

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(self.config.interval)
            sessions = list(self.context.sessions)
            connected = sum(1 for s in sessions if s.transitions.state == "connected")
            await self._set("uptime", f"{int(time.monotonic() - self._started)} seconds")
            await self._set("clients/connected", str(connected))
            await self._set("clients/total", str(len(sessions)))
            await self._set("subscriptions/count", str(sum(len(v) for v in self.context.subscriptions.values())))
            await self._set("retained messages/count", str(len(self.context.retained_messages)))
