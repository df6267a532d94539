"""The uplink's rate from what crosses the whole path to the broker, measured end to end. ROS-free, I/O-free.

Why: :class:`.uplink.LinkMeter` steers by the robot's own socket (the bytes the kernel holds unacknowledged, and the
kernel's delivered-bytes counter). That is the truth on a link whose queue backs up into the robot (a modem, a
cellular router), and a lie behind a hop that acknowledges the robot's bytes at once: a split-TCP proxy of a
cellular or satellite carrier, a VPN concentrator, a TLS or WebSocket load balancer in front of a cloud broker, a
site's HTTP proxy. There the socket looks empty while seconds of data wait behind the real bottleneck, and a
budget taken from the socket lets the queue grow without bound (issue 42 measured pose 5–9 s old and growing).

What this meter sees instead: **probes that cross the path and come back through the broker** (the bridge sends a
PINGREQ on its main connection; the broker's PINGRESP can only come once the PINGREQ has passed every queue before
it, hidden or not). One probe is out at a time, so

* each answer is a round-trip sample, and the age of the probe still out is a lower bound of the current one
  (a growing queue shows before its probe returns; a dead spot shows as an age that keeps growing);
* the **base delay** is the least round trip over the last :data:`BASE_HISTORY` seconds (the path with empty
  queues); **queueing delay** = current − base. That is the signal of LEDBAT, BBR and WebRTC's congestion control
  (Google Congestion Control), the reason video calls stay live on bad links;
* the bytes the bridge had handed over (all its connections) when a probe left have **crossed the path** when its
  answer comes: so the delivered rate between two answers is what the path carried end to end, and
  :meth:`PathMeter.in_flight` (handed over minus known to have crossed) is what waits in the path now, whatever the
  socket says.

The controller, one update per answer (and per look while a probe is overdue):

* queueing delay over the target (``uplink_target_delay``; on a fast path less: :attr:`PathMeter.target`, a few
  packets' time, at least FAST_TARGET, since whatever waits there waits ahead of an emergency stop's
  acknowledgement): the path is **over-used**; the rate becomes
  :data:`DECREASE` × what the path delivered recently (at most once per round trip, so one queue is not punished
  twice). A probe overdue by more than the target counts as over-use at once, before its answer;
* under half the target: **probe upward** by :data:`INCREASE` per second (multiplicative: from 128 kbit/s to
  1 Mbit/s in a few seconds), never beyond :data:`HEADROOM` × the most the path delivered lately, so a robot that
  sends little does not talk its estimate up to a flood (GCC's 1.5× bound); near the **capacity** found at the last
  cut (an answer's delivered rate; for a probe overdue, what the answers of the last second delivered) only by
  :data:`GENTLE_INCREASE` per second, until the rate passes :data:`FORGET_ABOVE` × it without a cut
  (CUBIC's and BBR's lesson: probe hard far from the last loss, gently near it);
* in between: hold.

When it steers (:meth:`PathMeter.steering`, :meth:`PathMeter.room`):

* **before the first answer**, only control leaves: the base round trip must be learnt on an empty path (a queue
  built before it would be taken for the path itself, and kept: the failure of the first attempt);
* **behind a hop** (:attr:`PathMeter.behind_a_hop`: the path's base round trip HOP_GAP longer than the main
  TCP connection's own, so something on the way acknowledges early), from the first answer on;
* **for STEER_FOR after a queue the sockets did not show was found** (a cut: a probe overdue or answered late
  by more than the target), the bytes beyond the robot's sockets and not yet known to have crossed stay under
  the path's budget, and the uplink's rate is at most the path's. Otherwise the socket's meter steers alone: on a
  link whose queue backs up into the robot it sees the queue itself, and a fast link's burst is never held to
  the path's estimate. A cut on a probe still out takes at most half the rate (a thread stalled on a busy
  machine looks the same as a queue until the answer comes), so a false one costs a fast link little: that
  halving, and a few seconds in which the rate grows gently near what the path delivered just before;
* a probe that waited behind the robot's own sockets (more than VISIBLE_SHARE of ``target_delay``, the socket
  meter's target) **cuts nothing**: on
  a link that serves connections in turns it also waits for the other connections' turns, which look like a
  queue and are not one (the second failure of the first attempt: 19 kbit/s on a 128 kbit/s modem).

A dead spot (no answer for a while) looks like a queue until its probe returns: the rate is cut a few times, each
cut waiting as long as the probe has been out (0.85× at ~0.2, 0.4, 0.8, 1.6 s …), and grows back by its answers
once the path returns; in-flight bytes stay capped all along, so nothing piles up behind the dead spot.

Limits: a probe measures the queue its own connection waits in; on a link that serves connections in turns rather
than first come first served, the other connections' queues show only partly (the socket signal still covers those
where they are visible). The downlink's queue adds to the round trip too (small for a robot, whose downlink carries
commands).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

PROBE_PERIOD = 0.1  # s between probes while the path answers promptly (one is out at a time)
BASE_HISTORY = 30.0  # s: the base delay is the least round trip of this long (a queue is drained well within it)
BASE_BUCKET = 5.0  # s per bucket of that history (the least of each kept; the oldest bucket leaves whole)
CURRENT_SAMPLES = 3  # the current delay is the least of the last few answers (one jittered sample is no queue)
RATE_WINDOW = 1.0  # s of answers the delivered rate is taken over
PEAK_WINDOW = 5.0  # s: the most delivered lately (what probing upward may reach past)
DECREASE = 0.85  # over-use: the rate becomes this much of what the path delivered (GCC's beta)
INCREASE = 0.5  # under-use: the rate grows by this fraction per second (1.5× per second)
FAST_INCREASE = 1.25  # per answer while the path shows no queue at all (under a quarter of the target)
HEADROOM = 1.5  # the rate never exceeds this × the most delivered lately
NEAR_CAPACITY = 0.85  # from this × the capacity found at the last cut, the rate grows gently …
GENTLE_INCREASE = 0.1  # … by this fraction per second
FORGET_ABOVE = 1.15  # the rate grew to this × that capacity without a cut: the link is faster, the capacity forgotten
CAPACITY_MEMORY = 10.0  # s: … or this long after it was found (a link changes)
MIN_RATE = 1_000.0  # bytes/s (8 kbit/s): the rate never falls below it, so the path always gets probes' worth
OVERDUE_FLOOR = 0.5  # a cut on a probe overdue (before its answer) leaves at least this × DECREASE of the rate
STEER_FOR = 30.0  # s: once a queue hidden from the sockets was found, the path steers for this long after the last
FIRST_WAIT = 1.0  # s: only control leaves until the first probe is answered, or this long after it left
HOP_GAP = 0.015  # s: a path round trip this much longer than the TCP connection's own says a hop acknowledges early
CLEAN_VISIBLE = 0.002  # s: a probe that waited longer than this behind the robot's own sockets teaches no base
VISIBLE_SHARE = 0.5  # a probe that waited more than this × the target behind the robot's own sockets cannot cut
CLEAR_QUEUE = 0.25  # × the target: answers whole within this of the base say nothing queues (shows_no_queue)
FAST_TARGET = 0.05  # s: the least queue target of a fast path (:attr:`PathMeter.target`) …
TARGET_PACKETS = 3  # … otherwise this many packets' time at the rate, up to the configured target
PACKET = 1_500  # bytes: one full packet on an Ethernet-sized path
FRESH_ANSWER = 0.5  # s: how recent the last answer must be for shows_no_queue to speak


@dataclass(slots=True)
class _Answer:
    at: float  # when the answer came
    rtt: float  # the round trip less the wait the robot could see (its own sockets' queue)
    crossed: int  # bytes handed over before the probe left: they have crossed the path now
    raw: float = 0.0  # the whole round trip, the wait behind the robot's own sockets included


@dataclass
class PathMeter:
    """End-to-end round trips and delivered bytes of the uplink, and the rate they allow (all times in seconds,
    from the caller's monotonic clock; byte counts are the bridge's own running total of bytes handed over)."""

    target_delay: float = 0.1  # s of queueing the path may hold (robots.yaml bridge.uplink_target_delay)
    rate: float = 125_000.0  # bytes/s: what the uplink may send (starts at the caller's guess)
    answers: int = 0
    last_answer: float | None = None  # when a probe was last answered: the broker was there then
    overused: int = 0  # decreases so far (state/link and tests read it)
    _sent_at: float | None = None  # the probe out, if any: when it left
    _sent_handed: int = 0  # and the bytes handed over before it
    _sent_visible: float = 0.0  # and the wait ahead of it that the robot's own sockets showed, s
    _last_sent: float = float("-inf")
    _crossed: int = 0  # bytes known to have crossed the path
    _recent: deque[_Answer] = field(default_factory=deque)  # answers of the last PEAK_WINDOW
    _buckets: deque[tuple[float, float]] = field(default_factory=deque)  # (bucket start, least rtt in it)
    _holds: dict[str, float] = field(default_factory=dict)  # kind of cut → no cut of that kind before this
    _grown_at: float | None = None  # when the rate last grew (or was cut): growth is per second since
    _rates: deque[tuple[float, float]] = field(default_factory=deque)  # (answer time, delivered rate) lately
    _answered_visible: float = 0.0  # the visible wait of the probe answered last, s
    _hidden_at: float | None = None  # when a queue the sockets did not show was last found (a cut)
    _first_sent: float | None = None  # when the first probe left
    tcp_rtt: float | None = None  # the kernel's least round trip of the main connection (to the first hop), s
    capacity: float | None = None  # bytes/s the path delivered when its queue last grew past the target (a cut)
    _capacity_at: float = 0.0  # when
    _capacity_probe: float | None = None  # the probe out (its departure) whose being overdue found it, if one did

    @property
    def target(self) -> float:
        """Seconds of queue the path may hold now: ``target_delay``, and on a fast path less, TARGET_PACKETS
        packets' time at the rate, at least FAST_TARGET. Why: whatever waits in a hidden queue waits ahead of
        every connection's bytes, an emergency stop's acknowledgement among them; the queue a path needs to stay
        busy is a few packets, and at 1 Mbit/s 100 ms is eight of them (the acknowledgement 2.3× its idle time
        behind a camera and a map, bench/weak_link.py). On a thin path a packet alone takes most of the target,
        and the target stays whole there (a smaller one cut a 128 kbit/s path for every packet)."""
        packets = TARGET_PACKETS * PACKET / self.rate if self.rate > 0 else self.target_delay
        return min(self.target_delay, max(FAST_TARGET, packets))

    # -- probes ----------------------------------------------------------------------------------------------
    def probe_due(self, now: float) -> bool:
        """True when a probe should leave now: none is out and the last left PROBE_PERIOD ago."""
        return self._sent_at is None and now - self._last_sent >= PROBE_PERIOD

    def probe_sent(self, now: float, handed: int, visible: float = 0.0) -> None:
        """A probe left at ``now``; ``handed``: the sender's byte clock then (bytes that had left the robot, all
        connections: they have crossed once it is answered); ``visible``: the seconds it will wait behind what the
        robot's own sockets hold (the socket's controller keeps that queue at its target already: this meter
        steers only by what is hidden beyond it)."""
        self._sent_at, self._sent_handed, self._last_sent = now, handed, now
        self._sent_visible = max(0.0, visible)
        if self._first_sent is None:
            self._first_sent = now

    def probe_answered(self, now: float) -> float | None:
        """The probe out was answered at ``now``: its round trip (None if no probe was out)."""
        if self._sent_at is None:
            return None
        raw = max(0.0, now - self._sent_at)
        rtt = max(0.0, raw - self._sent_visible)
        self._answered_visible = self._sent_visible
        self._sent_at = None
        self._crossed = max(self._crossed, self._sent_handed)
        self.answers += 1
        self.last_answer = now
        self._recent.append(_Answer(now, rtt, self._sent_handed, raw))
        while self._recent and now - self._recent[0].at > PEAK_WINDOW:
            self._recent.popleft()
        bucket = now - now % BASE_BUCKET
        if self._sent_visible > CLEAN_VISIBLE:
            pass  # the base only from probes that waited behind nothing of ours: the sockets' wait is an estimate
            # (their bytes over the rate), and an overestimate would make the base 0 and every answer a queue
        elif self._buckets and self._buckets[-1][0] == bucket:
            self._buckets[-1] = (bucket, min(self._buckets[-1][1], rtt))
        else:
            self._buckets.append((bucket, rtt))
        while self._buckets and now - self._buckets[0][0] > BASE_HISTORY:
            self._buckets.popleft()
        delivered = self.delivered_rate()
        if delivered is not None:
            self._rates.append((now, delivered))
        while self._rates and now - self._rates[0][0] > PEAK_WINDOW:
            self._rates.popleft()
        self.update(now, answered=True)
        return raw

    def reset(self, handed: int) -> None:
        """A new connection: the probe out is lost with the old one, and the new one is probed at once. What was
        handed over is not taken as crossed: the other connections' bytes may still wait behind a hop (the first
        attempt counted them crossed, and a thin hidden link that had just cost the main connection its
        keep-alive was flooded again at once); the new connection's first answer says what crossed. The base
        delay and the rate are kept."""
        self._sent_at, self._last_sent = None, float("-inf")
        self._crossed = min(self._crossed, handed)
        self.tcp_rtt = None  # (a failover may reach another broker, on another route)
        self.capacity = None  # (… whose capacity is its own)
        self._capacity_probe = None
        self._recent.clear()
        self._rates.clear()
        self._grown_at = None

    # -- signals ---------------------------------------------------------------------------------------------
    @property
    def measured(self) -> bool:
        """At least one answer: the delay signals mean something."""
        return bool(self._buckets)

    @property
    def base_rtt(self) -> float:
        """The least round trip of the last BASE_HISTORY seconds (0 before the first answer)."""
        return min((rtt for _, rtt in self._buckets), default=0.0)

    def current_rtt(self, now: float) -> float:
        """The round trip a message meets now: the least of the last few answers, or the age of the probe out
        when that is longer (a queue, or a dead spot, that grows before the probe's answer shows it)."""
        last = [a.rtt for a in list(self._recent)[-CURRENT_SAMPLES:]]
        answered = min(last) if last else self.base_rtt
        overdue = now - self._sent_at - self._sent_visible if self._sent_at is not None else 0.0
        return max(answered, overdue)

    def shows_no_queue(self, now: float) -> bool:
        """True when the path's latest answers came back at its base round trip, counted whole (the wait behind
        the robot's own sockets included), and no probe is overdue: nothing queues anywhere on the way, so bytes
        the robot's sockets hold are on their way, not a backlog.

        Why: the socket's meter takes a window in which its sockets held bytes at every look for a full link and
        its delivered bytes for the link's capacity. A paced lane trickles a burst at a time, so its socket holds
        a little at most looks however idle the link is: once one window had measured a stall, the meter took the
        trickle for the capacity, paced to it, and measured it again (a 1 Mbit/s link held at 50 kbit/s for
        minutes, scans 3 s old: bench/weak_link.py, one run in three). The probes are the check: on a full link
        they wait too."""
        if not self._recent or now - self._recent[-1].at > FRESH_ANSWER:
            return False
        if self._sent_at is not None and now - self._sent_at - self.base_rtt > CLEAR_QUEUE * self.target_delay:
            return False
        last = list(self._recent)[-CURRENT_SAMPLES:]
        return min(a.raw for a in last) - self.base_rtt < CLEAR_QUEUE * self.target_delay

    def queue_delay(self, now: float) -> float:
        """Seconds of queue in the path now: current − base (0 before the first answer)."""
        return max(0.0, self.current_rtt(now) - self.base_rtt) if self.measured else 0.0

    def in_flight(self, handed: int, now: float | None = None) -> int:
        """Bytes handed over and not yet known to have crossed the path (``handed``: the running total now).

        With ``now``: less what crossed at the rate since the last answer, for at most one probe period and base
        round trip (the answers come that far apart: without it the path would idle between them); a probe
        overdue beyond that earns nothing more, so a dead spot is not filled behind; nor does a path whose queue
        is over the target earn any."""
        unconfirmed = max(0, handed - self._crossed)
        if now is None or not self._recent or self.queue_delay(now) > self.target:
            return unconfirmed  # a path over its target carries less than the rate says: no credit on trust
        since = min(max(0.0, now - self._recent[-1].at), PROBE_PERIOD + self.base_rtt)
        return max(0, unconfirmed - int(self.rate * since))

    def _rate_over(self, until: float) -> float | None:
        """Bytes/s that crossed between the answers of the RATE_WINDOW before ``until``, or between the last two
        answers when they are further apart (a long queue answers seldom; None: fewer than two answers)."""
        answers = [a for a in self._recent if a.at <= until]
        if len(answers) < 2:
            return None
        last = answers[-1]
        first = next((a for a in answers if last.at - a.at <= RATE_WINDOW and a is not last), answers[-2])
        if last.at <= first.at:
            return None
        return (last.crossed - first.crossed) / (last.at - first.at)

    def delivered_rate(self) -> float | None:
        """Bytes/s that crossed the path over the last RATE_WINDOW of answers (None: not enough answers)."""
        return self._rate_over(self._recent[-1].at) if self._recent else None

    # -- the controller --------------------------------------------------------------------------------------
    @property
    def peak_rate(self) -> float:
        """The most the path delivered over RATE_WINDOW in the last PEAK_WINDOW, bytes/s (0: not measured)."""
        return max((rate for _, rate in self._rates), default=0.0)

    def update(self, now: float, answered: bool = False) -> float:
        """Move the rate by what the path shows now; returns it. Called on every answer (``answered``) and on
        every look of the sender: a probe overdue by more than the target is over-use before its answer comes."""
        if not self.measured:
            return self.rate
        queued = self.queue_delay(now)
        target = self.target
        if queued > target:
            # An answer measures what the path delivered: the rate goes below it. A probe overdue only says the
            # path is slower than the rate: a cut by DECREASE. Each kind waits a round trip (or the probe's age)
            # before cutting again, since a cut shows only after one: one queue is not punished twice.
            # A probe that waited behind the robot's own sockets is the socket's to steer: on a link that serves
            # connections in turns it also waits for the others' turns, which look like a queue and are not one.
            hold = "answer" if answered else "overdue"
            visible = self._answered_visible if answered else self._sent_visible
            if visible > VISIBLE_SHARE * self.target_delay:  # (the sockets' queue: the socket meter's target)
                self._grown_at = now
                return self.rate
            if now >= self._holds.get(hold, float("-inf")):
                self._hidden_at = now
                delivered = self.delivered_rate() if answered else self._overdue_bound(now)
                if delivered is not None and not answered:
                    # a probe overdue says little about how fast the path is (a stalled thread on a busy machine
                    # looks the same): at most a halving on it; its answer measures
                    delivered = max(delivered, OVERDUE_FLOOR * self.rate)
                basis = min(self.rate, delivered) if delivered is not None else self.rate
                # what a full path carries: an answer's delivered rate; for a probe overdue, what the answers of
                # the last RATE_WINDOW delivered, no more than the rate that overfilled the path (without it the
                # rate grew back 1.25× per answer after each overdue cut, past the capacity within half a second,
                # and a 1 Mbit/s path behind a hop went through a cut and a 200 ms queue every second or two)
                # (once per probe out: a dead spot's later cuts of the same probe find a rate cut already)
                lately = delivered if answered else self.delivered_rate()
                if lately is not None and lately > 0 and \
                        (answered or (self._sent_at is not None and self._capacity_probe != self._sent_at)):
                    self.capacity, self._capacity_at = (lately if answered else min(lately, self.rate)), now
                    self._capacity_probe = None if answered else self._sent_at
                self.rate = max(MIN_RATE, DECREASE * basis)
                self._holds[hold] = now + self.current_rtt(now)
                self.overused += 1
            self._grown_at = now
        elif not answered:
            return self.rate
        elif (latest := self._recent[-1].rtt - self.base_rtt if self._recent else queued) > queued:
            self._grown_at = now  # the last answer alone shows a queue: no growth on it (nor a cut: it may be jitter)
        elif queued < target / 2:
            since = now - self._grown_at if self._grown_at is not None else 0.0
            # no queue at all: grow per answer, as a path that has room shows within a round trip (a burst on a
            # fast link must not wait seconds for its rate); some queue: grow per second, gently
            grown = self.rate * (FAST_INCREASE if latest < target / 4 else 1.0 + INCREASE * min(since, 1.0))
            capacity = self.known_capacity(now)
            if capacity is None:
                self.capacity = None
            else:
                # the capacity found at the last cut: fast up to near it, gently from there (a per-answer growth
                # of 1.25 took a thin hidden link to 1.6 × its capacity between two cuts, and every lane with it)
                near = NEAR_CAPACITY * capacity
                gentle = self.rate * (1.0 + GENTLE_INCREASE * min(since, 1.0))
                grown = gentle if self.rate >= near else min(grown, max(near, gentle))
            peak = self.peak_rate
            ceiling = HEADROOM * peak if peak > 0 else grown
            self.rate = max(MIN_RATE, min(grown, max(self.rate, ceiling)))
            self._grown_at = now
        else:
            self._grown_at = now  # hold: no growth is owed for the time spent near the target
        return self.rate

    def known_capacity(self, now: float) -> float | None:
        """The capacity found at the last cut, while it still holds: forgotten CAPACITY_MEMORY after it was found,
        or once the rate has grown to FORGET_ABOVE × it without a cut (the link got faster). Not by what the path
        delivered: as a queue drains its probes come back in quick succession, and the bytes ahead of them make the
        path look faster than it is for an answer or two after every cut."""
        capacity = self.capacity
        if capacity is not None and (now - self._capacity_at > CAPACITY_MEMORY or self.rate > FORGET_ABOVE * capacity):
            return None  # (forgotten by update(), the one place the controller's state changes)
        return capacity

    def _overdue_bound(self, now: float) -> float | None:
        """The most the path can be delivering while a probe is out: the bytes handed over before it and not yet
        known to have crossed, over the time it has waited beyond the base round trip (they have not all crossed,
        or it would be answered). None while that says nothing."""
        if self._sent_at is None:
            return None
        waited = now - self._sent_at - self._sent_visible - self.base_rtt
        ahead = self._sent_handed - self._crossed
        return ahead / waited if waited > 0 and ahead > 0 else None

    def budget(self, now: float) -> int:
        """Bytes the path may hold at the rate: one base round trip plus the target's worth of queue."""
        return int(self.rate * (self.base_rtt + self.target))

    # -- steering --------------------------------------------------------------------------------------------
    def steering(self, now: float) -> bool:
        """True while the path, not only the socket, limits what is handed over: before the first answer (the
        base round trip must be learnt on an empty path: a queue built before it would be taken for the path
        itself, and kept; FIRST_WAIT at most), all along :attr:`behind_a_hop`, and for STEER_FOR after a queue the
        sockets did not show was found. Otherwise the socket's meter alone steers, as on a link whose queue backs
        up into the robot (and a fast link, whose bursts are never held to the path's estimate)."""
        if not self.measured:  # (a broker that never answers must not silence the robot: FIRST_WAIT)
            return self._first_sent is None or now - self._first_sent < FIRST_WAIT
        if self.behind_a_hop:
            return True
        return self._hidden_at is not None and now - self._hidden_at < STEER_FOR

    @property
    def behind_a_hop(self) -> bool:
        """The path's least round trip is HOP_GAP longer than the TCP connection's own: something between the
        robot and the broker acknowledges the robot's bytes before they have crossed (a split-TCP proxy, a VPN, a
        satellite terminal), so a queue may build where the socket cannot see it. The path then steers from the
        first answer on, growing from its first guess as its answers show room, instead of waiting for a queue
        to show: on a thin link that wait is seconds of data already in the hidden queue. On a LAN and on a path
        whose queue backs up into the robot both round trips are alike, and nothing changes there. It is decided
        from the first answer, and undone by the first fast one (a busy broker slow to answer at first): waiting
        for more answers let a camera fill a hidden 1 Mbit/s queue with seconds of frames first, and every
        connection of the bridge lost its keep-alive behind them."""
        return self.tcp_rtt is not None and self.measured and self.base_rtt - self.tcp_rtt > HOP_GAP

    def room(self, handed: int, held: int, now: float) -> int | None:
        """Bytes that may still be handed over beyond what the robot's sockets hold (``held``) while the path
        steers (None: it does not): its budget less what is on the way beyond the sockets and not yet known to
        have crossed. 0 before the first answer: only control leaves until the path is measured."""
        if not self.steering(now):
            return None
        if not self.measured:
            return 0
        return self.budget(now) - max(0, self.in_flight(handed, now) - held)
