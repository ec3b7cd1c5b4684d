"""The autopilot's clock on the companion's link time: from arrivals, and from TIMESYNC.

*Link time* is the companion's (Unix time on a real link, simulated time in lockstep);
*vehicle time* is the autopilot's boot clock, which stamps its estimates. The
*offset* ``link - vehicle`` (s) joins them: ``vehicle_time(t) = t - offset(t)``.

Two measurements, both pure functions of stamps (no clock is read here):

* **One way.** Every accepted pose message gives ``t_rx - t_msg = offset + latency +
  age >= offset``. The smallest over the last ``window_s`` is an upper bound on the
  offset, off by the smallest latency plus stamp age seen (a millisecond or so on UDP,
  more on a radio). It needs nothing sent, and is the estimate when no TIMESYNC answers.
* **Round trip (MAVLink TIMESYNC).** The companion sends ``ts1`` = its link time (ns);
  the autopilot answers with ``tc1`` = its own clock on receipt (ns); the answer
  arrives at ``t_rx``. The offset lies in ``[ts1 - tc1, t_rx - tc1]``; the midpoint
  ``(ts1 + t_rx) / 2 - tc1`` is exact when the two legs take equal time, and off by at
  most half the round trip otherwise. Only answers to requests this clock sent count.

From the round trips of the last ``sync_window_s`` whose round trip is within 1 ms of
the shortest (queueing only adds to a round trip, and to the error bound), a least-squares line
gives the offset and its drift: an autopilot's clock runs a little fast or slow
against the companion's (PX4 SITL's ran 0.8 % slow against the wall clock), so a
constant offset would age. With fewer than two such answers, or a span under 1 s, the
newest of the shortest round trips is used without drift.

Combining. The offset used is the smaller of the two: the TIMESYNC estimate removes
the latency and stamp age the one-way bound carries, and the one-way bound caps an
answer stamped late. Simulated autopilots stamp late: their clock moves in simulation
steps, so an answer carries the last step's time (PX4 SITL with SIH answered 8 to 59 ms
behind its pose stamps, mavsim before it advanced to the receipt time about 4 ms).

Consistency. An autopilot that answers TIMESYNC on another clock than the one that
stamps its poses (a Unix clock against a boot clock, say) would shift every estimate by
that difference. When the two estimates differ by more than ``max_disagreement_s``
(0.5 s: more than any link's latency) three answers in a row, TIMESYNC is set aside
for the rest of the run (:attr:`VehicleClock.disagrees`, which the caller announces).
When answers stop for ``sync_window_s``, the one-way bound is used alone until they resume.

Memory is bounded: at most 64 samples of each kind and 32 outstanding requests.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

DEFAULT_WINDOW_S = 2.0         # one-way: the minimum over this much recent link time
DEFAULT_SYNC_WINDOW_S = 5.0    # round trips used, and how long TIMESYNC stays in force after the last answer
_SAMPLES = 64
_PENDING = 32
_MAX_RTT_S = 1.0               # a longer round trip says nothing useful about a clock
_RTT_SLACK_S = 1e-3            # answers used: round trip within the shortest + this (each has error <= rtt / 2)
_MIN_FIT_SPAN_S = 1.0
_MAX_DRIFT = 0.1               # a clock 10 % off is broken, not drifting
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


class VehicleClock:
    """Maps link time onto the autopilot's boot clock (see the module docstring)."""

    def __init__(self, window_s: float = DEFAULT_WINDOW_S, sync_window_s: float = DEFAULT_SYNC_WINDOW_S,
                 max_disagreement_s: float = DEFAULT_MAX_DISAGREEMENT_S) -> None:
        self.window_s = float(window_s)
        self.sync_window_s = float(sync_window_s)
        self.max_disagreement_s = float(max_disagreement_s)
        self._one_way: deque[tuple[float, float]] = deque(maxlen=_SAMPLES)
        self._round_trips: deque[_RoundTrip] = deque(maxlen=_SAMPLES)
        self._pending: deque[int] = deque(maxlen=_PENDING)
        self._fit: tuple[float, float, float] | None = None  # (t_ref, offset at t_ref, drift)
        self._disagreeing = 0
        #: TIMESYNC answers disagreed with the pose stamps; it is no longer used.
        self.disagrees = False
        self.requests_sent = 0
        self.answers_used = 0
        self.answers_foreign = 0   # answers to requests this clock did not send (or sent too long ago)
        self.answers_discarded = 0  # negative or over 1 s round trips

    # ------------------------------------------------------------------ measurements

    def observe_pose(self, t_rx: float, t_msg: float) -> None:
        """An accepted pose stamped ``t_msg`` (vehicle s) arrived at link time ``t_rx`` (s)."""
        self._one_way.append((float(t_rx), float(t_rx) - float(t_msg)))

    def request(self, t_s: float) -> int:
        """The ``ts1`` (ns) of a TIMESYNC request sent at link time ``t_s``; remembered to match its answer."""
        ts1 = link_ns(t_s)
        self._pending.append(ts1)
        self.requests_sent += 1
        return ts1

    def answer(self, t_rx: float, tc1_ns: int, ts1_ns: int) -> bool:
        """A TIMESYNC answer (``tc1`` the autopilot's ns, ``ts1`` ours echoed) arrived at ``t_rx``; True if used."""
        if ts1_ns not in self._pending:
            self.answers_foreign += 1
            return False
        self._pending.remove(ts1_ns)
        rx_ns = link_ns(t_rx)  # integer nanoseconds: exact differences whatever the magnitude of link time
        rtt_ns = rx_ns - ts1_ns
        if not (0 <= rtt_ns <= _MAX_RTT_S * _NS):
            self.answers_discarded += 1
            return False
        offset_2ns = ts1_ns + rx_ns - 2 * tc1_ns  # twice the midpoint offset, an exact integer
        self._round_trips.append(_RoundTrip(float(t_rx), offset_2ns / (2 * _NS), rtt_ns / _NS))
        self.answers_used += 1
        self._fit = self._fit_round_trips(float(t_rx))
        self._check_agreement(float(t_rx))
        return True

    # ------------------------------------------------------------------ estimates

    def one_way_offset(self, t_s: float) -> float | None:
        """The one-way bound on the offset at link time ``t_s`` (s); None before any pose."""
        recent = [off for t, off in self._one_way if t >= t_s - self.window_s] or [off for _, off in self._one_way]
        return min(recent) if recent else None

    def sync_offset(self, t_s: float) -> float | None:
        """The TIMESYNC estimate of the offset at ``t_s`` (s); None when not in force."""
        if not self._round_trips or self.disagrees or self._disagreeing:  # none, set aside, or a disagreement pending
            return None
        if t_s - self._round_trips[-1].t_s > self.sync_window_s:  # the answers stopped
            return None
        return self._fitted(t_s)

    def _fitted(self, t_s: float) -> float | None:
        if self._fit is None:
            return None
        t_ref, offset, drift = self._fit
        return offset + drift * (t_s - t_ref)

    def offset(self, t_s: float) -> float | None:
        """Link minus vehicle time at link time ``t_s`` (s): the smaller of the TIMESYNC estimate
        (when in force) and the one-way bound; None before any pose."""
        one_way = self.one_way_offset(t_s)
        synced = self.sync_offset(t_s)
        if one_way is None or synced is None:
            return one_way
        return min(one_way, synced)

    def vehicle_time(self, t_s: float) -> float | None:
        """Vehicle time (s since its boot) at link time ``t_s``; None before any pose."""
        if not self._one_way:
            return None  # no pose yet: nothing to stamp against
        return t_s - self.offset(t_s)

    def summary(self, t_s: float | None = None) -> dict:
        """What the clock used, for run reports (times in s, link minus vehicle)."""
        t = t_s if t_s is not None else (self._one_way[-1][0] if self._one_way else None)
        synced = self.sync_offset(t) if t is not None else None
        one_way = self.one_way_offset(t) if t is not None else None
        rtts = [rt.rtt_s for rt in self._round_trips]
        if one_way is None:
            source = "none"
        else:
            source = "timesync" if synced is not None and synced < one_way else "arrivals"
        return {
            "source": source,
            "timesync_requests": self.requests_sent,
            "timesync_answers": self.answers_used,
            "timesync_foreign": self.answers_foreign,
            "timesync_disagrees": self.disagrees,
            "rtt_min_ms": 1e3 * min(rtts) if rtts else None,
            "drift": self._fit[2] if self._fit is not None else None,
            # how far the one-way bound sits above the TIMESYNC estimate: latency plus stamp age
            # (negative: the answers are stamped late, and the bound is used)
            "one_way_minus_timesync_ms": 1e3 * (one_way - synced) if synced is not None and one_way is not None else None,
        }

    # ------------------------------------------------------------------ internals

    def _fit_round_trips(self, t_now: float) -> tuple[float, float, float] | None:
        recent = [rt for rt in self._round_trips if rt.t_s >= t_now - self.sync_window_s]
        if not recent:
            return None
        rtt_cap = min(rt.rtt_s for rt in recent) + _RTT_SLACK_S
        good = [rt for rt in recent if rt.rtt_s <= rtt_cap]
        best = min(reversed(good), key=lambda rt: rt.rtt_s)  # the newest of the shortest
        without_drift = (best.t_s, best.offset_s, 0.0)
        t = np.array([rt.t_s for rt in good]) - t_now
        if len(good) < 2 or t[-1] - t[0] < _MIN_FIT_SPAN_S:
            return without_drift
        base = good[-1].offset_s
        y = np.array([rt.offset_s - base for rt in good])  # small numbers: link times are ~1e9 s
        slope, intercept = np.polyfit(t, y, 1)
        if not (math.isfinite(slope) and abs(slope) <= _MAX_DRIFT):
            return without_drift
        return (t_now, base + float(intercept), float(slope))

    def _check_agreement(self, t_now: float) -> None:
        synced = self._fitted(t_now)
        one_way = self.one_way_offset(t_now)
        if synced is None or one_way is None:
            return
        if abs(synced - one_way) > self.max_disagreement_s:
            self._disagreeing += 1
            if self._disagreeing >= _DISAGREEMENTS_TO_DROP:
                self.disagrees = True
        else:
            self._disagreeing = 0
