"""The QP recorder (companion/core/planner/qp_record.py): off by default, the same flight
when on, and a file whose QPs OSQP solves back to the planner's solutions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import osqp
import pytest

from companion.core.planner import qp_record
from companion.core.planner.osqp_qp import OsqpQp
from companion.offline.harness import run_lockstep

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = ROOT / "configs" / "antipodal.toml"
DURATION_S = 4.0


def _fly(tlog: Path) -> None:
    run_lockstep(SCENARIO, seed=0, duration_s=DURATION_S, tlog_path=tlog, stop_after_goal_s=None)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A short lockstep flight without and with the recorder: the two tlogs and the record."""
    d = tmp_path_factory.mktemp("qp_record")
    _fly(d / "off.tlog")
    rec = qp_record.QpRecorder(scene="antipodal")
    with qp_record.recording(rec):
        _fly(d / "on.tlog")
    assert qp_record.ACTIVE is None
    return d / "off.tlog", d / "on.tlog", rec.save(d / "antipodal.npz")


def test_off_by_default():
    from tests.benchmarks.bench_planner import OBSTACLES, config, request
    from companion.core.planner import Planner

    assert qp_record.ACTIVE is None
    planner = Planner(config("hyperplane"))
    planner.solve(request(0.0, np.array([0.0, 0.0, -5.0]), np.zeros(3), OBSTACLES))
    (ws,) = planner.workspaces.values()
    assert ws.recorder is None and type(ws.qp) is OsqpQp


def test_recording_leaves_the_flight_unchanged(recorded):
    off, on, _ = recorded
    assert off.read_bytes() == on.read_bytes()


def test_file_reads_back_with_its_tags_and_settings(recorded):
    *_, path = recorded
    with np.load(path) as z:
        assert str(z["format"]) == "companion-qp-record" and int(z["version"]) == 1
        count = int(z["count"])
    qps = qp_record.load(path)
    assert len(qps) == count > 5
    first = qps[0].meta
    assert first["replan"] == 1 and first["scp_iteration"] == 1 and first["qp_in_step"] == 0
    assert first["scene"] == "antipodal" and first["warm"] == "explicit"
    assert [q.meta["replan"] for q in qps] == sorted(q.meta["replan"] for q in qps)
    assert {q.meta["warm"] for q in qps} <= {"explicit", "previous"}
    for qp in qps:
        n, m = qp.P.shape[0], qp.A.shape[0]
        assert qp.A.shape == (m, n) and qp.q.shape == qp.x.shape == qp.x_warm.shape == (n,)
        assert qp.l.shape == qp.u.shape == qp.y.shape == qp.y_warm.shape == (m,)
        assert (qp.P != qp.P.tocsc().__class__(np.triu(qp.P.toarray()))).nnz == 0     # upper triangle
        assert qp.meta["eps_abs"] == 1e-4 and qp.meta["scaling"] == 0 and qp.meta["max_iter"] >= 1
        if qp.meta["status"] == "solved":
            assert np.isclose(qp.objective(qp.x), qp.meta["objective"], rtol=1e-9, atol=1e-9)


def test_osqp_reproduces_the_planners_solutions(recorded):
    """Set up from the file with the recorded settings and warm start, OSQP gives the planner's ``x``."""
    *_, path = recorded
    explicit = [qp for qp in qp_record.load(path) if qp.meta["warm"] == "explicit" and qp.meta["status"] == "solved"]
    assert len(explicit) >= 3
    for qp in explicit:
        m = qp.meta
        s = osqp.OSQP()
        s.setup(qp.P, qp.q, qp.A, qp.l, qp.u, eps_abs=m["eps_abs"], eps_rel=m["eps_rel"], eps_prim_inf=1e-6,
                eps_dual_inf=1e-6, polishing=m["polish"], verbose=False, warm_starting=True, max_iter=m["max_iter"],
                adaptive_rho=m["adaptive_rho"], scaling=m["scaling"], rho=m["rho"])
        s.warm_start(qp.x_warm, qp.y_warm)
        r = s.solve(raise_error=False)
        assert r.info.status == "solved"
        assert r.info.iter == m["iterations"]
        np.testing.assert_allclose(r.x, qp.x, rtol=0, atol=1e-9)
        assert qp.violation(r.x) <= 1e-2
