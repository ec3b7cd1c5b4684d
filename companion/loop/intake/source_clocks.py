"""Per-source clock mapping: a sender's timestamps onto the companion's time base.

Every obstacle source stamps its reports with its own clock (its boot clock, a Unix
clock, seconds after the hour...). The companion acts in *link time*: the time its
link stamped the report on arrival. :class:`SourceClock` estimates, per source, the
offset ``t_rx - t_msg`` from arrival times and maps each stamp onto link time::

    t_mapped = t_msg + offset(t_rx)

Offset. Latency only adds to ``t_rx - t_msg``, so the smallest value seen is the
best estimate of the true offset (the same rule the companion uses for the
autopilot's own clock). The arrivals of the last ``window_s`` seconds are binned
(``bin_s``); the minimum of each bin is a point on the lower envelope. With at least
``min_bins_for_drift`` bins a straight line through those minima gives the offset
and its drift (a sender clock running 1 % slow adds 0.01 s of offset per second);
with fewer, the minimum is used without drift. The line is lowered until no bin
minimum is below it, so it stays a lower envelope.

Jumps. A stamp whose residual against the current estimate exceeds ``jump_s`` (a
reboot, a wrapped counter, garbage such as ``0xFFFFFFFF``) restarts the source's
mapping: the history is dropped and the report starts a new epoch. The caller must
restart that source's track too (:attr:`Mapped.restarted`); a track is never frozen
by one bad stamp.

Future. A mapped time later than the arrival time is clamped to the arrival time
(:attr:`Mapped.clamped`): a report cannot describe the future. A stamp more than
``future_s`` ahead of the envelope (but within ``jump_s``) is clamped and kept out of
the offset estimate, so one bad stamp cannot drag the mapping.

Pure: no clocks, no threads. Stamps are kept as exact integers relative to the
first stamp of the epoch, so microsecond stamps of any magnitude (uint64) map
without rounding.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

logger = logging.getLogger(__name__)

DEFAULT_WINDOW_S = 10.0
DEFAULT_BIN_S = 1.0
DEFAULT_JUMP_S = 1.0
_CLAMP_REPORT_S = 1e-3  # futures below this are rounding of the envelope line: clamped, not reported
_MAX_BINS = 64
_MAX_DRIFT = 0.1  # a clock 10 % off is broken, not drifting  # bounds the history whatever window/bin ratio is configured


@dataclass(frozen=True)
class Mapped:
    """One stamp mapped onto link time.

    Attributes
    ----------
    t_s : float
        The report's time in link time, seconds (never after its arrival).
    restarted : bool
        The stamp jumped (or it is the first one): a new clock epoch began with this
        report and the source's track must restart.
    clamped : bool
        The stamp mapped more than 1 ms into the future (it is always clamped to the
        arrival time; less is rounding of the envelope).
    offset_s : float
        The estimated offset ``t_rx - t_msg`` at arrival, seconds.
    drift : float
        The estimated rate of change of the offset (dimensionless, s/s).
    """

    t_s: float
    restarted: bool
    clamped: bool
    offset_s: float
    drift: float


class SourceClock:
    """The clock mapping of one source.

    Parameters
    ----------
    window_s : float
        Seconds of arrivals the offset is estimated from (default 10 s).
    bin_s : float
        Width of the bins whose minima form the lower envelope (default 1 s).
    jump_s : float
        A residual larger than this (either sign) restarts the mapping (default 1 s).
    min_bins_for_drift : int
        Bins needed before a drift is fitted (default 3).
    future_s : float
        A stamp more than this ahead of the envelope (but within ``jump_s``) is a report
        from the future: clamped to its arrival and not used for the offset (default 0.1 s).
    """

    def __init__(
        self,
        *,
        window_s: float = DEFAULT_WINDOW_S,
        bin_s: float = DEFAULT_BIN_S,
        jump_s: float = DEFAULT_JUMP_S,
        min_bins_for_drift: int = 3,
        future_s: float = 0.1,
    ) -> None:
        if not (window_s > 0 and bin_s > 0 and jump_s > 0):
            raise ValueError(f"clock window, bin and jump must be > 0 s, got {window_s}, {bin_s}, {jump_s}")
        self.window_s = float(window_s)
        self.bin_s = float(bin_s)
        self.jump_s = float(jump_s)
        self.min_bins_for_drift = max(2, int(min_bins_for_drift))
        self.future_s = float(future_s)
        self.epochs = 0
        self._origin: int | float | None = None  # raw stamp that starts the epoch
        self._unit = 1.0
        self._bins: deque[list[float]] = deque(maxlen=_MAX_BINS)  # [bin start t_rx, t_rx at min, min offset]
        self._last_rel: float | None = None
        self._last_t_rx = 0.0  # arrival of the last stamp mapped (drift is evaluated there by peek)
        self._fit: tuple[float, float, float] | None = None  # (offset at t_mean, drift, t_mean) of the bins now

    def _relative(self, raw: int | float, unit_s: float) -> float:
        assert self._origin is not None
        if isinstance(raw, int) and isinstance(self._origin, int):
            return (raw - self._origin) * unit_s  # exact integer difference first
        return (float(raw) - float(self._origin)) * unit_s

    def estimate(self, t_rx: float) -> tuple[float, float] | None:
        """(offset at ``t_rx``, drift) of the current epoch, or None before any stamp."""
        if not self._bins:
            return None
        if self._fit is None:  # the bins changed since the last fit
            self._fit = self._fit_envelope()
        lower, drift, t_mean = self._fit
        if math.isnan(t_mean):
            return lower, drift
        return lower + drift * (t_rx - t_mean), drift

    def _fit_envelope(self) -> tuple[float, float, float]:
        """(offset at the mean bin time, drift, that mean time) of the bins' lower envelope; NaN time: no drift yet."""
        pts = np.array([(b[1], b[2]) for b in self._bins])
        if len(pts) < self.min_bins_for_drift:
            return float(pts[:, 1].min()), 0.0, math.nan
        t, off = pts[:, 0], pts[:, 1]
        # numpy's mean is this sum over n, without its per-call Python layer (a fit per change of the bins)
        n = len(pts)
        t_mean, off_mean = np.add.reduce(t) / n, np.add.reduce(off) / n
        tc = t - t_mean
        denom = float(np.dot(tc, tc))
        drift = float(np.dot(tc, off - off_mean) / denom) if denom > 1e-12 else 0.0
        drift = max(-_MAX_DRIFT, min(_MAX_DRIFT, drift))
        line = off_mean + drift * tc
        lower = float(off_mean - (line - off).max())  # lower the line onto the envelope
        return lower, drift, t_mean

    def map(self, raw: int | float, t_rx: float, unit_s: float = 1.0) -> Mapped:
        """Map one stamp; ``raw * unit_s`` is the sender's time in seconds.

        Parameters
        ----------
        raw : int or float
            The stamp as sent (e.g. ``time_usec`` with ``unit_s = 1e-6``).
        t_rx : float
            Arrival time on the link, seconds (link time).
        unit_s : float
            Seconds per unit of ``raw``.
        """
        if not math.isfinite(float(raw)) or not math.isfinite(t_rx):
            raise ValueError(f"stamp {raw!r} or arrival {t_rx!r} is not finite")
        restarted = False
        if self._origin is None or unit_s != self._unit:
            restarted = self._restart(raw, unit_s)
        rel = self._relative(raw, unit_s)
        est = self.estimate(t_rx)
        if est is not None:
            residual = (t_rx - rel) - est[0]
            if abs(residual) > self.jump_s:
                logger.info("clock jump of %.3f s (stamp %r): restarting the mapping", -residual, raw)
                restarted = self._restart(raw, unit_s)
                rel = 0.0
            elif residual < -self.future_s:
                # Stamped ahead of every other report: clamped, and kept out of the envelope.
                return Mapped(t_s=t_rx, restarted=False, clamped=True, offset_s=est[0], drift=est[1])
        self._add(t_rx, t_rx - rel)
        offset, drift = self.estimate(t_rx)  # type: ignore[misc]  # just added a point
        t_map = rel + offset
        clamped = t_map > t_rx + _CLAMP_REPORT_S
        t_map = min(t_map, t_rx)
        self._last_rel = rel
        self._last_t_rx = t_rx
        return Mapped(t_s=t_map, restarted=restarted, clamped=clamped, offset_s=offset, drift=drift)

    def peek(self, raw: int | float, unit_s: float = 1.0) -> float | None:
        """Link time (s) of a stamp by the current estimate, leaving the estimate as it is; None
        before any stamp of this epoch, in another unit, or non-finite.

        For stamps that are not arrival-like: a time the sender names (for example the start
        of a plan it announces, which may lie ahead of its sending) says nothing about the
        link's delay, so it must not shape the envelope; nor is it clamped to arrival.
        """
        if self._origin is None or unit_s != self._unit or not math.isfinite(float(raw)) or self._last_rel is None:
            return None
        rel = self._relative(raw, unit_s)
        est = self.estimate(self._last_t_rx)
        return None if est is None else rel + est[0]

    def _restart(self, raw: int | float, unit_s: float) -> bool:
        self._origin = raw if isinstance(raw, int) else float(raw)
        self._unit = unit_s
        self._bins.clear()
        self._fit = None
        self._last_rel = None
        self.epochs += 1
        return True

    def _add(self, t_rx: float, offset: float) -> None:
        # the fit is a function of the bins: it is dropped only when they change (a new
        # minimum, a new bin, an old bin out of the window), not at every report
        if self._bins and t_rx - self._bins[-1][0] < self.bin_s:
            b = self._bins[-1]
            if offset < b[2]:
                b[1], b[2] = t_rx, offset
                self._fit = None
        else:
            self._bins.append([t_rx, t_rx, offset])
            self._fit = None
        while self._bins and t_rx - self._bins[0][0] > self.window_s:
            self._bins.popleft()
            self._fit = None
