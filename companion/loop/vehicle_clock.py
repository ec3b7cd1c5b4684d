"""The autopilot's clock on the companion's link time: from arrivals, and from TIMESYNC.

*Link time* is the companion's (Unix time on a real link, simulated time in lockstep);
*vehicle time* is the autopilot's boot clock, which stamps its estimates. The
*offset* ``link - vehicle`` (s) joins them: ``vehicle_time(t) = t - offset(t)``.

Two measurements, both pure functions of stamps (no clock is read here):

* **One way.** Every accepted pose message gives ``t_rx - t_msg = offset + latency +
  age >= offset``. The smallest over the last ``window_s`` (0.5 s: 15 to 25 poses at an
  autopilot's 30 to 50 Hz) is an upper bound on the offset, off by the smallest latency
  plus stamp age seen (a millisecond or so on UDP, more on a radio). It follows the
  autopilot's clock at the pose rate, whatever that clock does.
* **Round trip (MAVLink TIMESYNC).** The companion sends ``ts1`` = its link time (ns);
  the autopilot answers with ``tc1`` = its own clock on receipt (ns); the answer
  arrives at ``t_rx``. The offset lies in ``[ts1 - tc1, t_rx - tc1]``; the midpoint
  ``(ts1 + t_rx) / 2 - tc1`` is exact when the two legs take equal time, and off by at
  most half the round trip otherwise. Only answers to requests this clock sent count.

Combining. The round trips measure what the one-way bound carries: at each answer, the
bound less the midpoint is the latency plus stamp age of the poses (the *excess*). Of the
answers of the last ``sync_window_s`` whose round trip is within 1 ms of the shortest
(queueing only adds to a round trip, and to the error), the newest gives the excess in
force, and the offset used is the one-way bound less that excess, never less than nothing.
So TIMESYNC removes the latency of a radio link (30 ms each way is 30 ms in every
estimate's age), and an answer stamped late cannot move the mapping: a simulated
autopilot's clock moves in simulation steps, so its answers carry the last step's time
(PX4 SITL with SIH answered 7 to 59 ms behind its pose stamps), a negative excess.

Why the one-way bound leads. A simulated autopilot's clock is not the wall clock: PX4
SITL's runs slower than it, more so the more the host's CPUs are taken, by steps and at
varying rates (docs/notes/vehicle_clock.md). Any estimate of the offset older than the
newest poses then lags, and puts every estimate further in the past than it is: enough,
with a long window or an extrapolated line, to judge a flowing estimate stale
(``estimate_timeout_s``) and brake. The bound over ``window_s`` lags by at most the
clock's slip over that window; the excess, a property of the link, does not drift.

Consistency. An autopilot that answers TIMESYNC on another clock than the one that
stamps its poses (a Unix clock against a boot clock, say) would shift every estimate by
that difference. When the excess is larger than ``max_disagreement_s`` (0.5 s: more than
any link's latency) three answers in a row, TIMESYNC is set aside for the rest of the
run (:attr:`VehicleClock.disagrees`, which the caller announces). When answers stop for
``sync_window_s``, the one-way bound is used alone until they resume.

Memory is bounded: at most 64 samples of each kind and 32 outstanding requests.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

DEFAULT_WINDOW_S = 0.5         # one-way: the minimum over this much recent link time
DEFAULT_SYNC_WINDOW_S = 5.0    # round trips used, and how long TIMESYNC stays in force after the last answer
_SAMPLES = 64
_PENDING = 32
_MAX_RTT_S = 1.0               # a longer round trip says nothing useful about a clock
_RTT_SLACK_S = 1e-3            # answers used: round trip within the shortest + this (each has error <= rtt / 2)
_MIN_RATE_SPAN_S = 1.0         # the reported drift needs this much link time between its two ends
DEFAULT_MAX_DISAGREEMENT_S = 0.5
_DISAGREEMENTS_TO_DROP = 3
_NS = 1_000_000_000


def link_ns(t_s: float) -> int:
    """Link time (s) as the integer nanoseconds TIMESYNC carries."""
    return int(round(float(t_s) * _NS))


@dataclass(frozen=True)
class _RoundTrip:
    t_s: float       # arrival of the answer, link time (s)
    offset_s: float  # midpoint estimate of link - vehicle (s)
    rtt_s: float
    excess_s: float  # the one-way bound at the answer less the midpoint: latency plus stamp age (s)


class VehicleClock:
    """Maps link time onto the autopilot's boot clock (see the module docstring).

    Parameters
    ----------
    window_s : float
        Link time (s) over which the smallest ``t_rx - t_msg`` of the poses is the one-way bound.
    sync_window_s : float
        Link time (s) of TIMESYNC answers the excess is taken from; answers older than this are not in force.
    max_disagreement_s : float
        An excess larger than this (s), three answers in a row, sets TIMESYNC aside for good.
    """

    def __init__(self, window_s: float = DEFAULT_WINDOW_S, sync_window_s: float = DEFAULT_SYNC_WINDOW_S,
                 max_disagreement_s: float = DEFAULT_MAX_DISAGREEMENT_S) -> None:
        self.window_s = float(window_s)
        self.sync_window_s = float(sync_window_s)
        self.max_disagreement_s = float(max_disagreement_s)
        self._one_way: deque[tuple[float, float]] = deque(maxlen=_SAMPLES)
        self._round_trips: deque[_RoundTrip] = deque(maxlen=_SAMPLES)
        self._pending: deque[int] = deque(maxlen=_PENDING)
        self._first: tuple[float, float] | None = None  # the first one-way bound (link s, offset s), for the drift
        self._disagreeing = 0
        #: TIMESYNC answers disagreed with the pose stamps; it is no longer used.
        self.disagrees = False
        self.requests_sent = 0
        self.answers_used = 0
        self.answers_foreign = 0   # answers to requests this clock did not send (or sent too long ago)
        self.answers_discarded = 0  # negative or over 1 s round trips, or answered before any pose

    # ------------------------------------------------------------------ measurements

    def observe_pose(self, t_rx: float, t_msg: float) -> None:
        """An accepted pose stamped ``t_msg`` (vehicle s) arrived at link time ``t_rx`` (s)."""
        self._one_way.append((float(t_rx), float(t_rx) - float(t_msg)))
        if self._first is None:
            self._first = (float(t_rx), float(t_rx) - float(t_msg))

    def request(self, t_s: float) -> int:
        """The ``ts1`` (ns) of a TIMESYNC request sent at link time ``t_s``; remembered to match its answer."""
        ts1 = link_ns(t_s)
        self._pending.append(ts1)
        self.requests_sent += 1
        return ts1

    def answer(self, t_rx: float, tc1_ns: int, ts1_ns: int) -> bool:
        """A TIMESYNC answer (``tc1`` the autopilot's ns, ``ts1`` ours echoed) arrived at ``t_rx``; True if used."""
        measured = self._round_trip(t_rx, tc1_ns, ts1_ns)
        if measured is None:
            return False
        one_way = self.one_way_offset(float(t_rx))
        if one_way is None:           # before any pose: nothing for the answer to measure
            self.answers_discarded += 1
            return False
        offset, rtt = measured
        self._round_trips.append(_RoundTrip(float(t_rx), offset, rtt, one_way - offset))
        self.answers_used += 1
        self._check_agreement(self._round_trips[-1].excess_s)
        return True

    def _round_trip(self, t_rx: float, tc1_ns: int, ts1_ns: int) -> tuple[float, float] | None:
        """(midpoint offset, round trip) in s of an answer to one of this clock's requests; None, counted,
        for someone else's answer or a round trip that is negative or over :data:`_MAX_RTT_S`."""
        if ts1_ns not in self._pending:
            self.answers_foreign += 1
            return None
        self._pending.remove(ts1_ns)
        rx_ns = link_ns(t_rx)  # integer nanoseconds: exact differences whatever the magnitude of link time
        rtt_ns = rx_ns - ts1_ns
        if not 0 <= rtt_ns <= _MAX_RTT_S * _NS:
            self.answers_discarded += 1
            return None
        return (ts1_ns + rx_ns - 2 * tc1_ns) / (2 * _NS), rtt_ns / _NS  # twice the midpoint is an exact integer

    # ------------------------------------------------------------------ estimates

    def one_way_offset(self, t_s: float) -> float | None:
        """The one-way bound on the offset at link time ``t_s`` (s); None before any pose."""
        if not self._one_way:
            return None
        recent = [off for t, off in self._one_way if t >= t_s - self.window_s]
        return min(recent) if recent else self._one_way[-1][1]  # silent for a window: the newest is the best bound

    def excess(self, t_s: float) -> float | None:
        """The one-way bound's latency plus stamp age in force at ``t_s`` (s), as TIMESYNC measured it;
        None when no answer is in force (none, set aside, a disagreement pending, or answers stopped)."""
        if not self._round_trips or self.disagrees or self._disagreeing:
            return None
        recent = [rt for rt in self._round_trips if rt.t_s >= t_s - self.sync_window_s]
        if not recent:  # the answers stopped
            return None
        rtt_cap = min(rt.rtt_s for rt in recent) + _RTT_SLACK_S
        return next(rt for rt in reversed(recent) if rt.rtt_s <= rtt_cap).excess_s  # the newest of the shortest

    def sync_offset(self, t_s: float) -> float | None:
        """The TIMESYNC estimate of the offset at ``t_s`` (s): the one-way bound less the excess; None when not in force."""
        one_way, excess = self.one_way_offset(t_s), self.excess(t_s)
        return None if one_way is None or excess is None else one_way - excess

    def offset(self, t_s: float) -> float | None:
        """Link minus vehicle time at link time ``t_s`` (s): the one-way bound less the excess TIMESYNC
        measured when that is positive (the smaller of the two estimates); None before any pose."""
        one_way = self.one_way_offset(t_s)
        excess = self.excess(t_s)
        if one_way is None or excess is None:
            return one_way
        return one_way - max(0.0, excess)

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) at link time ``t_s``; None before any pose."""
        if not self._one_way:
            return None  # no pose yet: nothing to stamp against
        return t_s - self.offset(t_s)

    def summary(self, t_s: float | None = None) -> dict:
        """What the clock used, for run reports (times in s, link minus vehicle)."""
        t = t_s if t_s is not None else (self._one_way[-1][0] if self._one_way else None)
        excess = self.excess(t) if t is not None else None
        one_way = self.one_way_offset(t) if t is not None else None
        rtts = [rt.rtt_s for rt in self._round_trips]
        if one_way is None:
            source = "none"
        else:
            source = "timesync" if excess is not None and excess > 0.0 else "arrivals"
        drift = None
        if one_way is not None and self._first is not None and t - self._first[0] >= _MIN_RATE_SPAN_S:
            drift = (one_way - self._first[1]) / (t - self._first[0])  # > 0: the autopilot's clock runs slow
        return {
            "source": source,
            "timesync_requests": self.requests_sent,
            "timesync_answers": self.answers_used,
            "timesync_foreign": self.answers_foreign,
            "timesync_disagrees": self.disagrees,
            "rtt_min_ms": 1e3 * min(rtts) if rtts else None,
            "drift": drift,
            # how far the one-way bound sits above the TIMESYNC estimate: latency plus stamp age
            # (negative: the answers are stamped late, and the bound is used)
            "one_way_minus_timesync_ms": 1e3 * excess if excess is not None else None,
        }

    # ------------------------------------------------------------------ internals

    def _check_agreement(self, excess: float) -> None:
        if abs(excess) > self.max_disagreement_s:
            self._disagreeing += 1
            if self._disagreeing >= _DISAGREEMENTS_TO_DROP:
                self.disagrees = True
        else:
            self._disagreeing = 0
