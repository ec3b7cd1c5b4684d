"""The autopilot's clock as companions before 8 December 2026 mapped it, to replay their logs exactly.

``[companion] vehicle_clock = "timesync_line"``. The one-way bound is the smallest ``t_rx -
t_msg`` over 2 s of pose arrivals (all of them when none is that recent); a least-squares
line with drift is fitted through the TIMESYNC round trips of the last ``sync_window_s``
whose round trip is within 1 ms of the shortest (the newest of the shortest alone, without
drift, with fewer than two or a span under 1 s); the offset used is the smaller of the line
and the bound. An autopilot's clock that slows under load makes both lag it
(:mod:`companion.loop.vehicle_clock`, "Why the one-way bound leads"); fly with the default.
"""

from __future__ import annotations

import math

import numpy as np

from companion.loop.vehicle_clock import _RTT_SLACK_S, VehicleClock, _RoundTrip

WINDOW_S = 2.0
_MIN_FIT_SPAN_S = 1.0
_MAX_DRIFT = 0.1               # a clock 10 % off is broken, not drifting


class TimesyncLineClock(VehicleClock):
    """:class:`VehicleClock` with the older mapping (see the module docstring)."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**{"window_s": WINDOW_S, **kwargs})
        self._fit: tuple[float, float, float] | None = None  # (t_ref, offset at t_ref, drift)

    def answer(self, t_rx: float, tc1_ns: int, ts1_ns: int) -> bool:
        measured = self._round_trip(t_rx, tc1_ns, ts1_ns)
        if measured is None:
            return False
        offset, rtt = measured
        self._round_trips.append(_RoundTrip(float(t_rx), offset, rtt, math.nan))
        self.answers_used += 1
        self._fit = self._fit_round_trips(float(t_rx))
        synced, one_way = self._fitted(float(t_rx)), self.one_way_offset(float(t_rx))
        if synced is not None and one_way is not None:
            self._check_agreement(one_way - synced)
        return True

    def one_way_offset(self, t_s: float) -> float | None:
        recent = [off for t, off in self._one_way if t >= t_s - self.window_s] or [off for _, off in self._one_way]
        return min(recent) if recent else None

    def sync_offset(self, t_s: float) -> float | None:
        if not self._round_trips or self.disagrees or self._disagreeing:
            return None
        if t_s - self._round_trips[-1].t_s > self.sync_window_s:
            return None
        return self._fitted(t_s)

    def excess(self, t_s: float) -> float | None:
        """The bound less the line (reported only)."""
        one_way, synced = self.one_way_offset(t_s), self.sync_offset(t_s)
        return None if one_way is None or synced is None else one_way - synced

    def offset(self, t_s: float) -> float | None:
        one_way, synced = self.one_way_offset(t_s), self.sync_offset(t_s)
        if one_way is None or synced is None:
            return one_way
        return min(one_way, synced)

    def _fitted(self, t_s: float) -> float | None:
        if self._fit is None:
            return None
        t_ref, offset, drift = self._fit
        return offset + drift * (t_s - t_ref)

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
