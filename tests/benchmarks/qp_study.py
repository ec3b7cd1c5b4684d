"""Solver study on the planner's recorded QPs (issue 40, item 1).

    PYTHONPATH=$PWD python -m tests.benchmarks.qp_record /tmp/qprec     # the QPs (about 20 s)
    PYTHONPATH=$PWD python -m tests.benchmarks.qp_study /tmp/qprec      # the table

Every recorded QP (:mod:`companion.core.planner.qp_record`) is solved by each solver
through its own Python API, the solvers taking turns QP by QP in one run (so a busy
machine slows them alike), each ``--repeats`` times; a QP's time is the median of its
repeats, wall clock (``time.perf_counter``) around the solver's calls only (the
conversion of the recorded arrays into each solver's input is done before, untimed).

- ``osqp (planner)``: as the planner runs it: one solver per QP shape set up once (not
  timed) with the planner's settings (``eps_abs``, ``eps_rel``, ``rho``, ``scaling=0``,
  adaptive ``rho``, no polish, the recorded ``max_iter``); per QP the timed calls are the
  in-place data update (numerical refactorisation), ``rho`` restored, the warm start with
  the recorded ``x``, ``y`` and the solve.
- ``osqp (setup)``: the same, set up anew for every QP (timed): what every other solver pays.
- ``clarabel``, ``piqp`` (interior point; no warm start), ``proxsuite`` (ProxQP, sparse,
  warm-started with ``x``, ``y``), ``qpalm`` (warm-started), ``daqp`` (dense active set,
  warm-started with ``x``, ``y``; automatic proximal regularisation as ``P`` is only
  semidefinite): set up and solved per QP, tolerances ``eps_abs = eps_rel`` = the planner's
  (1e-4; for the interior-point solvers the gap and feasibility tolerances).

Rows with ``l = u`` are passed as equalities to the solvers that separate them. The
reference is Clarabel at 1e-9 (gap and feasibility); a QP it finds primal infeasible (the
planner's hard QPs whose safety rows cannot all hold) is counted apart: a solver's answer
there is right when it reports infeasibility or stops unsolved. Accuracy on the other QPs:
``|f - f_ref| / max(1, |f_ref|)`` and the largest violation of ``l <= Ax <= u`` (row units),
each solver's p99 and largest; a failure is a status other than solved (or a non-finite
``x``) on a QP the reference solved.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from companion.core.planner.qp_record import RecordedQp, load

OSQP_INF = 1e30
BIG = 1e20
#: A solve slower than this is not repeated (seconds): the study's time stays bounded.
NO_REPEAT_S = 0.1


# ---------------------------------------------------------------------------------- solvers
class Solver:
    """One solver: ``prepare(qp)`` builds its inputs (untimed), ``run(prepared)`` solves (timed).

    ``run`` returns ``(x, status, solved, infeasible)``, ``x`` a copy: a solver's result array
    may be a view of memory its next solve overwrites (PIQP's ``result.x``).
    """

    name = ""

    def prepare(self, qp: RecordedQp):
        return qp

    def run(self, prep):
        raise NotImplementedError


def _split(qp: RecordedQp):
    """Row indices of equalities (``l = u``) and of the other rows with a finite bound (rows
    without one, the obstacle rows out of sensing range, are left out)."""
    eq = np.isfinite(qp.l) & (qp.l == qp.u)
    free = ~np.isfinite(qp.l) & ~np.isfinite(qp.u)
    return np.flatnonzero(eq), np.flatnonzero(~eq & ~free)


class OsqpPlanner(Solver):
    name = "osqp (planner)"

    def __init__(self) -> None:
        self._solvers: dict = {}

    def prepare(self, qp):
        import osqp

        key = (qp.meta["shape"], qp.meta["scene"])
        if key not in self._solvers:
            s = osqp.OSQP()
            m = qp.meta
            s.setup(qp.P, qp.q, qp.A, np.maximum(qp.l, -OSQP_INF), np.minimum(qp.u, OSQP_INF), eps_abs=m["eps_abs"],
                    eps_rel=m["eps_rel"], eps_prim_inf=1e-6, eps_dual_inf=1e-6, polishing=m["polish"],
                    verbose=False, warm_starting=True, max_iter=m["max_iter"], adaptive_rho=True, scaling=0,
                    rho=m["rho"])
            self._solvers[key] = [s, s._solver, m["max_iter"]]
        entry = self._solvers[key]
        if entry[2] != qp.meta["max_iter"]:
            entry[0].update_settings(max_iter=qp.meta["max_iter"])
            entry[2] = qp.meta["max_iter"]
        return (entry[1], qp.P.data, qp.A.data, qp.q, np.maximum(qp.l, -OSQP_INF), np.minimum(qp.u, OSQP_INF),
                qp.meta["rho"], qp.x_warm, qp.y_warm)

    def run(self, prep):
        ext, px, ax, q, l, u, rho, xw, yw = prep
        ext.update_data_vec(q=q, l=l, u=u)
        ext.update_data_mat(P_x=px, P_i=None, A_x=ax, A_i=None)
        ext.update_rho(rho)
        ext.warm_start(xw, yw)
        ext.solve()
        info = ext.info
        return np.array(ext.solution.x, dtype=float), info.status, info.status_val == 1, info.status_val in (3, 4)


class OsqpSetup(Solver):
    name = "osqp (setup)"

    def prepare(self, qp):
        return qp, np.maximum(qp.l, -OSQP_INF), np.minimum(qp.u, OSQP_INF)

    def run(self, prep):
        import osqp

        qp, l, u = prep
        m = qp.meta
        s = osqp.OSQP()
        s.setup(qp.P, qp.q, qp.A, l, u, eps_abs=m["eps_abs"], eps_rel=m["eps_rel"], eps_prim_inf=1e-6,
                eps_dual_inf=1e-6, polishing=m["polish"], verbose=False, warm_starting=True, max_iter=m["max_iter"],
                adaptive_rho=True, scaling=0, rho=m["rho"])
        s.warm_start(qp.x_warm, qp.y_warm)
        r = s.solve(raise_error=False)
        return np.array(r.x, dtype=float), r.info.status, r.info.status_val == 1, r.info.status_val in (3, 4)


class Clarabel(Solver):
    name = "clarabel"

    def __init__(self, tol: float | None = None, max_iter: int = 200) -> None:
        self.tol, self.max_iter = tol, max_iter
        if tol is not None:
            self.name = f"clarabel {tol:g} (reference)"

    def prepare(self, qp):
        import clarabel

        eq, ineq = _split(qp)
        A = qp.A.tocsr()
        up = ineq[np.isfinite(qp.u[ineq])]
        lo = ineq[np.isfinite(qp.l[ineq])]
        a = sp.vstack([A[eq], A[up], -A[lo]]).tocsc()
        b = np.concatenate([qp.u[eq], qp.u[up], -qp.l[lo]])
        cones = [clarabel.ZeroConeT(len(eq)), clarabel.NonnegativeConeT(len(up) + len(lo))]
        st = clarabel.DefaultSettings()
        st.verbose = False
        tol = self.tol if self.tol is not None else qp.meta["eps_abs"]
        st.tol_gap_abs = st.tol_gap_rel = st.tol_feas = tol
        st.max_iter = self.max_iter
        return qp.P.tocsc(), qp.q, a, b, cones, st

    def run(self, prep):
        import clarabel

        s = clarabel.DefaultSolver(*prep)
        r = s.solve()
        st = str(r.status)
        return np.array(r.x, dtype=float), st, st in ("Solved", "AlmostSolved"), "PrimalInfeasible" in st


class Piqp(Solver):
    name = "piqp"

    def prepare(self, qp):
        eq, ineq = _split(qp)
        A = qp.A.tocsr()
        return (qp.P.tocsc(), qp.q, A[eq].tocsc(), qp.u[eq], A[ineq].tocsc(), qp.l[ineq], qp.u[ineq],
                qp.meta["eps_abs"], qp.meta["eps_rel"])

    def run(self, prep):
        import piqp

        P, c, Aeq, b, G, hl, hu, ea, er = prep
        s = piqp.SparseSolver()
        s.settings.eps_abs, s.settings.eps_rel = ea, er
        s.settings.verbose = False
        s.setup(P, c, Aeq, b, G, hl, hu)
        status = s.solve()
        return np.array(s.result.x, dtype=float), str(status), status == piqp.PIQP_SOLVED, status == piqp.PIQP_PRIMAL_INFEASIBLE


class PiqpUpdate(Solver):
    """PIQP kept per shape and set of equality (and free) rows: ``update`` (numerical refactorisation) when the
    pattern is the same as the previous QP's, else a new ``setup`` (timed either way)."""

    name = "piqp (update)"

    def __init__(self) -> None:
        self._solvers: dict = {}

    def prepare(self, qp):
        import piqp

        eq, ineq = _split(qp)
        A = qp.A.tocsr()
        key = (qp.meta["shape"], qp.meta["scene"], qp.P.shape, qp.P.nnz, qp.A.nnz, eq.tobytes(), ineq.tobytes())
        fresh = key not in self._solvers
        if fresh:
            s = piqp.SparseSolver()
            s.settings.eps_abs, s.settings.eps_rel = qp.meta["eps_abs"], qp.meta["eps_rel"]
            s.settings.verbose = False
            self._solvers[key] = s
        return (self._solvers[key], fresh, qp.P.tocsc(), qp.q, A[eq].tocsc(), qp.u[eq], A[ineq].tocsc(), qp.l[ineq],
                qp.u[ineq])

    def run(self, prep):
        import piqp

        s, fresh, P, c, Aeq, b, G, hl, hu = prep
        if fresh:
            s.setup(P, c, Aeq, b, G, hl, hu)
        else:
            s.update(P=P, c=c, A=Aeq, b=b, G=G, h_l=hl, h_u=hu)
        status = s.solve()
        return np.array(s.result.x, dtype=float), str(status), status == piqp.PIQP_SOLVED, status == piqp.PIQP_PRIMAL_INFEASIBLE


class Proxsuite(Solver):
    name = "proxsuite"

    def prepare(self, qp):
        eq, ineq = _split(qp)
        A = qp.A.tocsr()
        return (qp.P.shape[0], qp.P.tocsc(), qp.q, A[eq].tocsc(), qp.u[eq], A[ineq].tocsc(),
                np.maximum(qp.l[ineq], -BIG), np.minimum(qp.u[ineq], BIG), qp.meta["eps_abs"], qp.meta["eps_rel"],
                qp.x_warm, qp.y_warm[eq], qp.y_warm[ineq], qp.meta["max_iter"])

    def run(self, prep):
        import proxsuite

        n, H, g, A, b, C, l, u, ea, er, xw, yw, zw, mi = prep
        s = proxsuite.proxqp.sparse.QP(n, A.shape[0], C.shape[0])
        s.settings.eps_abs, s.settings.eps_rel = ea, er
        s.settings.max_iter = mi
        s.settings.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START
        s.init(H, g, A, b, C, l, u)
        s.solve(xw, yw, zw)
        st = s.results.info.status
        return (np.array(s.results.x, dtype=float), str(st), st == proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED,
                st == proxsuite.proxqp.QPSolverOutput.PROXQP_PRIMAL_INFEASIBLE)


class Qpalm(Solver):
    name = "qpalm"

    def prepare(self, qp):
        import qpalm

        eq, ineq = _split(qp)
        rows = np.sort(np.concatenate([eq, ineq]))
        n, m = qp.P.shape[0], len(rows)
        data = qpalm.Data(n, m)
        data.Q = qp.P.tocsc()
        data.q = qp.q
        data.A = qp.A.tocsr()[rows].tocsc()
        data.bmin = np.maximum(qp.l[rows], -BIG)
        data.bmax = np.minimum(qp.u[rows], BIG)
        st = qpalm.Settings()
        st.eps_abs, st.eps_rel = qp.meta["eps_abs"], qp.meta["eps_rel"]
        st.verbose = 0
        st.max_iter = qp.meta["max_iter"]
        return data, st, qp.x_warm, qp.y_warm[rows]

    def run(self, prep):
        import qpalm

        data, st, xw, yw = prep
        s = qpalm.Solver(data, st)
        s.warm_start(xw, yw)
        s.solve()
        status = s.info.status
        return np.array(s.solution.x, dtype=float), status, status == "solved", status == "primal infeasible"


class Daqp(Solver):
    name = "daqp"

    def prepare(self, qp):
        eq, _ = _split(qp)
        sense = np.zeros(qp.A.shape[0], dtype=np.int32)
        sense[eq] = 5
        H = np.ascontiguousarray(qp.P_full.toarray())
        return (H, np.ascontiguousarray(qp.q), np.ascontiguousarray(qp.A.toarray()),
                np.ascontiguousarray(np.minimum(qp.u, OSQP_INF)), np.ascontiguousarray(np.maximum(qp.l, -OSQP_INF)),
                sense, qp.meta["eps_abs"], np.ascontiguousarray(qp.x_warm), np.ascontiguousarray(qp.y_warm))

    def run(self, prep):
        import daqp

        H, f, A, bu, bl, sense, eps, xw, yw = prep
        x, _, flag, _ = daqp.solve(H, f, A, bu, bl, sense, primal_start=xw, dual_start=yw, eps_prox=-1.0,
                                   primal_tol=eps, dual_tol=eps)
        return np.array(x, dtype=float), str(flag), flag in (1, 2), flag == -1


CANDIDATES = {"osqp": OsqpSetup, "clarabel": Clarabel, "piqp": Piqp, "piqp-update": PiqpUpdate, "proxsuite": Proxsuite, "qpalm": Qpalm,
              "daqp": Daqp}


# ---------------------------------------------------------------------------------- the study
def _timed(solver: Solver, prep, repeats: int):
    """Median wall time of ``repeats`` solves (one when the first took over :data:`NO_REPEAT_S`), the last answer."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        try:
            out = solver.run(prep)
        except Exception as e:  # noqa: BLE001 - a solver error is a failure in the table
            out = (None, f"error: {type(e).__name__}: {e}", False, False)
        times.append(time.perf_counter() - t0)
        if times[0] > NO_REPEAT_S:
            break
    return float(np.median(times)), out


def study(paths: list[Path], names: list[str], repeats: int, every: int) -> dict:
    qps: list[RecordedQp] = []
    for p in paths:
        qps.extend(load(p)[::every])
    ref = Clarabel(tol=1e-9)
    solvers = [OsqpPlanner()] + [CANDIDATES[n]() for n in names]
    res = {s.name: {"t": [], "fail": [], "obj": [], "viol": [], "inf_ok": 0, "inf_t": [], "feas_t": [], "status": {}}
           for s in solvers}
    n_inf, ref_fail, planner_dx = 0, 0, []
    replan_of = [(q.meta["scene"], q.meta["replan"]) for q in qps]
    for i, qp in enumerate(qps):
        x_ref, st_ref, ok_ref, inf_ref = ref.run(ref.prepare(qp))
        if not ok_ref and not inf_ref:
            ref_fail += 1
        n_inf += inf_ref
        f_ref = qp.objective(x_ref) if ok_ref else math.nan
        for s in solvers:
            prep = s.prepare(qp)
            t, (x, st, ok, inf) = _timed(s, prep, repeats)
            r = res[s.name]
            r["t"].append(t)
            if inf_ref:
                r["inf_t"].append(t)
                r["inf_ok"] += bool(inf or not ok)
                continue
            if not ok_ref:
                continue
            r["feas_t"].append(t)
            good = ok and x is not None and bool(np.isfinite(x).all())
            if not good:
                r["fail"].append(i)
                r["status"][str(st)] = r["status"].get(str(st), 0) + 1
                continue
            r["obj"].append(abs(qp.objective(x) - f_ref) / max(1.0, abs(f_ref)))
            r["viol"].append(qp.violation(x))
            if s.name == "osqp (planner)" and qp.meta["warm"] == "explicit":
                planner_dx.append(float(np.max(np.abs(x - qp.x))))
        if (i + 1) % 200 == 0:
            print(f"  {i + 1} of {len(qps)} QPs", file=sys.stderr, flush=True)
    return {"qps": len(qps), "infeasible": n_inf, "ref_fail": ref_fail, "res": res, "planner_dx": planner_dx,
            "replan_of": replan_of,
            "solvers": [s.name for s in solvers], "sizes": sorted({(q.P.shape[0], q.A.shape[0]) for q in qps})}


def _family(scene: str) -> str:
    return "bench" if scene.startswith("bench") else scene.split("_")[0]


def table(out: dict) -> str:
    res = out["res"]
    base = np.median(res["osqp (planner)"]["t"])
    base99 = np.percentile(res["osqp (planner)"]["t"], 99)
    lines = [f"{out['qps']} QPs (n x m: {', '.join(f'{n}x{m}' for n, m in out['sizes'])}); "
             f"{out['infeasible']} primal infeasible per the reference, reference failed on {out['ref_fail']}",
             "",
             "| solver | median ms | p99 ms | largest ms | median / OSQP (planner) | p99 / OSQP (planner) | "
             "feasible QPs: p99 ms | failures | infeasible answered (median ms) | obj. diff p99 | obj. diff max | "
             "violation p99 | violation max |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in out["solvers"]:
        r = res[name]
        t = np.asarray(r["t"]) * 1e3
        obj, viol = np.asarray(r["obj"] or [np.nan]), np.asarray(r["viol"] or [np.nan])
        fails = f"{len(r['fail'])}" + (f" ({', '.join(f'{k}: {v}' for k, v in r['status'].items())})" if r["fail"] else "")
        ft, it = np.asarray(r["feas_t"] or [np.nan]) * 1e3, np.asarray(r["inf_t"] or [np.nan]) * 1e3
        lines.append(f"| {name} | {np.median(t):.3f} | {np.percentile(t, 99):.2f} | {t.max():.2f} | "
                     f"{np.median(r['t']) / base:.2f} | {np.percentile(r['t'], 99) / base99:.2f} | "
                     f"{np.percentile(ft, 99):.2f} | {fails} | {r['inf_ok']} of {out['infeasible']} "
                     f"({np.median(it):.2f}) | "
                     f"{np.percentile(obj, 99):.1e} | {obj.max():.1e} | {np.percentile(viol, 99):.1e} | "
                     f"{viol.max():.1e} |")
    # the recorded QPs of each replan summed: each solver's time for the planner's QP sequence
    keys = sorted(set(map(tuple, out["replan_of"])))
    index = {k: i for i, k in enumerate(keys)}
    group = np.array([index[tuple(k)] for k in out["replan_of"]])
    sums = {name: np.bincount(group, weights=res[name]["t"], minlength=len(keys)) * 1e3 for name in out["solvers"]}
    lines += ["", f"Summed over the recorded QPs of each replan ({len(keys)} replans; the QPs the planner solved "
                  "with OSQP, not a replan run on the solver):", "",
              "| solver | median ms | p99 ms | largest ms | p99 / OSQP (planner) |", "|---|---|---|---|---|"]
    b99 = np.percentile(sums["osqp (planner)"], 99)
    for name in out["solvers"]:
        t = sums[name]
        lines.append(f"| {name} | {np.median(t):.2f} | {np.percentile(t, 99):.2f} | {t.max():.2f} | "
                     f"{np.percentile(t, 99) / b99:.2f} |")
    # per family of sets: the benchmark scenes, the corridor, the antipodal flights, the survey
    family = np.array([_family(k[0]) for k in out["replan_of"]])
    names = sorted(set(family))
    lines += ["", "Per set, solve time median / p99 ms (each QP):", "",
              "| solver | " + " | ".join(f"{f} ({int(np.sum(family == f))} QPs)" for f in names) + " |",
              "|---|" + "---|" * len(names)]
    for name in out["solvers"]:
        t = np.asarray(res[name]["t"]) * 1e3
        lines.append(f"| {name} | " + " | ".join(f"{np.median(t[family == f]):.2f} / {np.percentile(t[family == f], 99):.2f}"
                                               for f in names) + " |")
    dx = np.asarray(out["planner_dx"] or [np.nan])
    lines += ["", f"osqp (planner) against the planner's own solutions (QPs it started from an explicit warm "
                  f"start, {len(out['planner_dx'])}): largest |x - x_planner| {dx.max():.1e}"]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input", help="a directory of recorded .npz files (tests.benchmarks.qp_record) or one file; "
                                  "or a .json written by --save: print its tables again")
    ap.add_argument("--solvers", default=",".join(CANDIDATES), help="comma-separated, of: " + ", ".join(CANDIDATES))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--every", type=int, default=1, help="study every k-th QP of each file")
    ap.add_argument("--save", help="also write the raw per-QP results to this JSON file")
    args = ap.parse_args(argv)
    src = Path(args.input)
    if src.suffix == ".json":
        print(table(json.loads(src.read_text())))
        return 0
    paths = sorted(src.glob("*.npz")) if src.is_dir() else [src]
    names = [n for n in args.solvers.split(",") if n]
    for n in names:
        if n not in CANDIDATES:
            ap.error(f"unknown solver {n}")
    t0 = time.perf_counter()
    out = study(paths, names, args.repeats, args.every)
    if args.save:
        Path(args.save).write_text(json.dumps(out, default=float))
    print(table(out))
    print(f"\n{len(paths)} files, repeats {args.repeats}, every {args.every}; {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
