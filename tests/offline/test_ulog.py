"""PX4 ULogs in ``companion identify``: the same model as from the same flight's tlog.

``tests/data/px4_steps.ulg`` and ``px4_steps.tlog`` are one PX4 SITL flight of
``companion fly --identify --arm --takeoff-alt 5`` (PX4 main 02e73e3b6f, SIH), cut to its
OFFBOARD stretch by :func:`tests.support.ulog_writer.flight_excerpt` (131 KB and 210 KB of
the 21.9 MB ULog and 1.7 MB tlog; the ULog keeps every third local position, about 42 Hz).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyulog")

from companion.offline import identify as ident  # noqa: E402
from companion.offline.ulog import UlogError, _change_times, is_ulog, load_ulog_series  # noqa: E402
from companion.mavlink.tlog import TlogError, read_tlog  # noqa: E402
from tests.support.ulog_writer import POSITION_FIELDS, SETPOINT_FIELDS, STATUS_FIELDS, write_ulog  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / "data"
ULOG, TLOG = DATA / "px4_steps.ulg", DATA / "px4_steps.tlog"
REPO = Path(__file__).resolve().parents[2]


def same_model(a: ident.Identification, b: ident.Identification, log: ident.ResponseLog) -> dict:
    """Per axis group: rms of the two models' open-loop velocities under ``log``'s commands, and the fit rms of ``a``."""
    out = {}
    for name, axes in (("horizontal", (0, 1)), ("vertical", (2,))):
        data = ident._axis_data(log, axes)
        ma, mb = getattr(a, name), getattr(b, name)
        diff = np.concatenate([ident._states(ma, ident.GRID_S, c, v[0])[:, 1] - ident._states(mb, ident.GRID_S, c, v[0])[:, 1]
                               for c, v in data])
        out[name] = (float(np.sqrt(np.mean(diff**2))), ident.fit_rms(ma, data),
                     ident.one_step_rms(ma, data), ident.one_step_rms(mb, data))
    return out


#: PX4's default logger profile keeps ``trajectory_setpoint`` every 200 ms (logged_topics.cpp).
LOGGER_INTERVAL_S = 0.2


def median_setpoint_gap_s(ulog: Path) -> float:
    """The median gap between the ``trajectory_setpoint`` samples a ULog kept, seconds.

    Samples carry their publish time (every 50 ms at the companion's 20 Hz), so the gaps are
    0.15 to 0.25 s around a median of 0.208 s at the 0.2 s interval.
    """
    from pyulog import ULog

    data = next(d for d in ULog(str(ulog), ["trajectory_setpoint"]).data_list if d.multi_id == 0)
    return float(np.median(np.diff(np.asarray(data.data["timestamp"], dtype=float)))) * 1e-6


def logger_spread(tlog: Path, interval_s: float, phases: int = 8) -> dict:
    """Per axis group, the worst model difference and 0.3 s-ahead rms against the tlog's model
    when the tlog's own setpoints are kept only every ``interval_s``, each change put at the
    middle of its interval as :func:`companion.offline.ulog._change_times` does.

    ``phases`` phases, each locked to the 20 Hz stream (every step lands at the same point of an
    interval): the worst case of what a ULog's sampling can do.

    A ULog's setpoints are known to half the logger's interval; this is how far that alone moves
    the fit (measured on tests/data/px4_steps.tlog at 0.2 s: up to 0.045 m/s vertical, against a fit rms of 0.080).
    """
    series = ident._tlog_series(tlog)
    log = ident.response_log(tlog, series)
    base = ident.identify(log)
    worst: dict[str, list[float]] = {}
    for phase in np.arange(phases) * interval_s / phases:
        kept = np.arange(series.sp_t[0] + phase, series.sp_t[-1], interval_s)
        idx = np.searchsorted(series.sp_t, kept, side="right") - 1
        v, p = series.sp_v[idx], series.sp_p[idx]
        sampled = dataclasses.replace(series, sp_t=_change_times(kept, v, p), sp_v=v, sp_p=p)
        model = ident.identify(ident.response_log(tlog, sampled))
        for name, (diff, _, _, one) in same_model(base, model, log).items():
            w = worst.setdefault(name, [0.0, 0.0])
            w[0], w[1] = max(w[0], diff), max(w[1], one)
    return worst


def assert_same_model_as_tlog(tlog: Path, ulog: Path) -> None:
    """The ULog's model is the tlog's, within what the ULog's setpoint sampling alone can move it."""
    from_tlog_log = ident.load_response_log(tlog)
    from_tlog = ident.identify(from_tlog_log)
    from_ulog = ident.identify(ident.load_response_log(ulog))
    assert abs(median_setpoint_gap_s(ulog) - LOGGER_INTERVAL_S) < 0.1 * LOGGER_INTERVAL_S, "not PX4's default logger profile"
    spread = logger_spread(tlog, LOGGER_INTERVAL_S)
    for name, (model_diff, fit, one_t, one_u) in same_model(from_tlog, from_ulog, from_tlog_log).items():
        worst_diff, worst_one = spread[name]
        print(f"{name}: models differ {model_diff:.4f} m/s rms (sampling alone: up to {worst_diff:.4f}), fit rms {fit:.3f}, "
              f"0.3 s-ahead {one_t:.3f} / {one_u:.3f} (sampling alone: up to {worst_one:.3f})")
        # no further from the tlog's model than the logger's sampling makes (a wrong axis, sign,
        # time unit or topic would be far outside)
        assert model_diff <= 1.25 * worst_diff + 0.005, (name, model_diff, worst_diff, fit)
        # and predicts the tlog's velocities one planner step ahead as well as a sampled tlog does
        assert one_u <= 1.05 * worst_one, (name, one_t, one_u, worst_one)


def test_ulog_gives_the_model_of_its_tlog_within_the_loggers_sampling():
    assert is_ulog(ULOG) and not is_ulog(TLOG)
    assert_same_model_as_tlog(TLOG, ULOG)
    assert ident.identify(ident.load_response_log(ULOG)).kinds["topic"] == "trajectory_setpoint"


def test_identify_cli_reads_a_ulog_by_its_magic(tmp_path):
    renamed = tmp_path / "flight.bin"             # the magic, not the name, says what it is
    renamed.write_bytes(ULOG.read_bytes())
    out = subprocess.run([sys.executable, "-m", "companion.cli", "identify", str(renamed), "--json"],
                         capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    assert summary["duration_s"] > 60
    assert 1.0 < summary["horizontal"]["p_gain_per_s"] < 2.5
    assert "not a tlog" not in out.stderr


def test_replay_names_a_ulog_instead_of_hex():
    with pytest.raises(TlogError, match="is a PX4 ULog, not a tlog"):
        list(read_tlog(ULOG))


def _synthetic(tmp_path: Path, *, lag_s: float = 0.4, status: bool = True) -> Path:
    """A ULog built here: OFFBOARD velocity steps and a vehicle that follows them with a first-order lag."""
    dt_us = 10_000                                                     # 100 Hz
    t = np.arange(0, 40_000_000, dt_us, dtype=np.uint64) + np.uint64(5_000_000)
    steps = [(0.0, 0.0, 0.0), (1.5, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, -2.0, 0.0), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0)]
    cmd = np.array([steps[min(int((ti - 5_000_000) // 6_000_000), len(steps) - 1)] for ti in t], dtype=float)
    vel = np.zeros_like(cmd)
    a = np.exp(-dt_us * 1e-6 / lag_s)
    for i in range(1, len(t)):
        vel[i] = a * vel[i - 1] + (1 - a) * cmd[i - 1]
    pos = np.cumsum(vel, axis=0) * dt_us * 1e-6
    sp_idx = np.arange(0, len(t), 5)                                   # setpoints at 20 Hz
    topics = {
        "vehicle_local_position": (POSITION_FIELDS, {"timestamp": t, "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                                                     "vx": vel[:, 0], "vy": vel[:, 1], "vz": vel[:, 2]}),
        "trajectory_setpoint": (SETPOINT_FIELDS, {"timestamp": t[sp_idx], "position": np.full((len(sp_idx), 3), np.nan),
                                                  "velocity": cmd[sp_idx]}),
    }
    if status:
        st_t = np.array([1_000_000, 4_000_000, 46_000_000], dtype=np.uint64)
        topics["vehicle_status"] = (STATUS_FIELDS, {"timestamp": st_t, "nav_state": np.array([4, 14, 4], dtype=np.uint8),
                                                     "arming_state": np.array([2, 2, 2], dtype=np.uint8)})
    return write_ulog(tmp_path / "built.ulg", topics, start_us=1_000_000)


def test_a_ulog_built_here_is_read_and_fitted(tmp_path):
    from pyulog import ULog

    path = _synthetic(tmp_path)
    assert {d.name for d in ULog(str(path)).data_list} == {"vehicle_local_position", "trajectory_setpoint", "vehicle_status"}
    series = load_ulog_series(path)
    assert series.kinds == {"velocity": 800, "position+velocity": 0, "topic": "trajectory_setpoint"}  # 40 s at 20 Hz
    result = ident.identify(ident.response_log(path, series))
    # a first-order lag of 0.4 s is in the model's family: the fit is near exact
    assert result.figures["model"]["fit_rms_all"] < 0.02
    assert result.figures["first-order fit"]["one_step_rms_all"] < 0.01


def test_a_ulog_without_vehicle_status_is_named(tmp_path):
    with pytest.raises(UlogError, match="no vehicle_status"):
        load_ulog_series(_synthetic(tmp_path, status=False))


def test_missing_view_extra_is_one_line_exit_2(tmp_path):
    code = ("import sys, builtins; real = builtins.__import__\n"
            "def imp(name, *a, **k):\n"
            "    if name.startswith('pyulog'): raise ImportError(name)\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = imp\n"
            "from companion.cli import main; sys.exit(main(['identify', sys.argv[1]]))\n")
    out = subprocess.run([sys.executable, "-c", code, str(ULOG)], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip().count("\n") == 0 and "view extra" in out.stderr, out.stderr
