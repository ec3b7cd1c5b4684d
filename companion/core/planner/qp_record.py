"""Recording the planner's QPs to a file (for solver studies; off by default).

Nothing is recorded unless a :class:`QpRecorder` is made active with :func:`recording`
*before* the planner first solves a QP shape: the planner's workspace then builds a
:class:`RecordingOsqpQp` (an :class:`OsqpQp` that keeps a copy of its data) instead of an
:class:`OsqpQp`. Without a recorder the planner's only extra work is one ``is None`` test
per SCP iteration, and its results are the same bits either way (the recording solver
passes every call on unchanged).

File format ``companion-qp-record`` version 1: one ``.npz`` (``numpy.savez_compressed``)
per recorded set, keys

- ``format`` (str ``"companion-qp-record"``), ``version`` (int 1), ``count`` (int, QPs);
- ``meta``: a JSON string, a list with one object per QP (index ``i``), with
  ``shape`` (index of its sparsity pattern), ``scene`` (the set's label), ``replan``
  (1-based count of replans seen by the recorder), ``scp_iteration`` (1-based within the
  replan), ``qp_in_step`` (0-based solve within the SCP iteration: the hard QP, then the
  least-violation QPs), ``warm`` (``"explicit"``: the planner called ``warm_start(x, y)``
  before this solve; ``"previous"``: OSQP started from the previous solve's iterate,
  recorded here as that solve's ``x``, ``y``; ``"cold"``: zeros after setup), the
  planner's OSQP settings ``eps_abs``, ``eps_rel``, ``max_iter`` (this solve's cap, the
  work budget's grant), ``rho`` (restored before every solve), ``polish``, ``scaling``
  (0), ``adaptive_rho`` (true), and what the planner got: ``status``, ``iterations``,
  ``objective`` (OSQP's ``0.5 x'Px + q'x``), ``solve_time_s`` (OSQP's own);
- ``shape{k}/P_indptr``, ``shape{k}/P_indices`` (``P``'s upper triangle, CSC),
  ``shape{k}/A_indptr``, ``shape{k}/A_indices`` (``A``, CSC), ``shape{k}/n``, ``shape{k}/m``;
- ``qp{i}/P_data``, ``qp{i}/A_data`` (data in the CSC order of the shape's pattern),
  ``qp{i}/q``, ``qp{i}/l``, ``qp{i}/u`` (bounds as the planner passed them: ``±inf`` for
  none; OSQP clips them at its infinity), ``qp{i}/x_warm``, ``qp{i}/y_warm`` (the start),
  ``qp{i}/x``, ``qp{i}/y`` (the planner's solution).

The QP is ``min 0.5 x'Px + q'x  s.t.  l <= Ax <= u``. Read with :func:`load`.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from companion.core.planner.osqp_qp import MAX_ITER, OsqpQp, QpSolution
from companion.core.planner.qp_layout import QpLayout

FORMAT = "companion-qp-record"
VERSION = 1

#: The active recorder (None: nothing is recorded). Set with :func:`recording`.
ACTIVE: QpRecorder | None = None


@dataclass(frozen=True)
class RecordedQp:
    """One recorded QP (``min 0.5 x'Px + q'x  s.t.  l <= Ax <= u``) and how the planner solved it.

    ``P`` is the upper triangle (CSC), as OSQP takes it; ``meta`` the JSON object of the
    file format (tags, settings, the planner's status and iterations).
    """

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    l: np.ndarray
    u: np.ndarray
    x_warm: np.ndarray
    y_warm: np.ndarray
    x: np.ndarray
    y: np.ndarray
    meta: dict

    @property
    def P_full(self) -> sp.csc_matrix:
        """The symmetric ``P``."""
        return sp.csc_matrix(self.P + sp.triu(self.P, k=1).T)

    def objective(self, x: np.ndarray) -> float:
        """``0.5 x'Px + q'x``."""
        return float(0.5 * x @ (self.P_full @ x) + self.q @ x)

    def violation(self, x: np.ndarray) -> float:
        """Largest violation of ``l <= Ax <= u`` at ``x`` (units of the rows)."""
        ax = self.A @ x
        return float(max(np.max(self.l - ax, initial=0.0), np.max(ax - self.u, initial=0.0)))


class QpRecorder:
    """Collects the QPs the planner solves while active (see :func:`recording`).

    Parameters
    ----------
    scene : str
        Label written into every QP's ``scene`` tag (may be changed between runs).
    max_qps : int
        Record at most this many QPs (later ones are counted in ``dropped``).
    """

    def __init__(self, scene: str = "", max_qps: int = 100_000) -> None:
        self.scene = scene
        self.max_qps = int(max_qps)
        self.replan = 0
        self.scp_iteration = 0
        self.qp_in_step = 0
        self.dropped = 0
        self._shapes: list[tuple[np.ndarray, ...]] = []
        self._shape_index: dict[int, int] = {}
        self._layouts: list[QpLayout] = []      # kept alive: their ids key _shape_index
        self._qps: list[tuple[dict, dict]] = []

    def __len__(self) -> int:
        return len(self._qps)

    def scp_step(self, first: bool) -> None:
        """The planner starts an SCP iteration (``first``: of a new replan)."""
        if first:
            self.replan += 1
            self.scp_iteration = 0
        self.scp_iteration += 1
        self.qp_in_step = 0

    def solver(self, layout: QpLayout, *args, **kwargs) -> RecordingOsqpQp:
        """The solver the planner's workspace uses while this recorder is active."""
        return RecordingOsqpQp(self, layout, *args, **kwargs)

    def _shape(self, qp: RecordingOsqpQp) -> int:
        key = id(qp.layout)
        if key not in self._shape_index:
            self._layouts.append(qp.layout)
            p = qp.layout.p_matrix(np.ones(len(qp.data["P_data"])))
            a = qp.layout.a_matrix_csc(np.ones(len(qp.data["A_data"])))
            self._shape_index[key] = len(self._shapes)
            self._shapes.append((p.indptr.copy(), p.indices.copy(), a.indptr.copy(), a.indices.copy(),
                                 np.int64(qp.layout.n), np.int64(qp.layout.m)))
        return self._shape_index[key]

    def add(self, qp: RecordingOsqpQp, sol: QpSolution, max_iter: int) -> None:
        """Record the QP ``qp`` just solved (its data, its start) and the planner's ``sol``."""
        in_step = self.qp_in_step
        self.qp_in_step += 1
        if len(self._qps) >= self.max_qps:
            self.dropped += 1
            return
        meta = {"shape": self._shape(qp), "scene": self.scene, "replan": self.replan,
                "scp_iteration": self.scp_iteration, "qp_in_step": in_step, "warm": qp.warm_kind,
                **qp.settings, "max_iter": int(max_iter), "status": sol.status, "iterations": sol.iterations,
                "objective": sol.objective, "solve_time_s": sol.solve_time_s}
        arrays = {k: v.copy() for k, v in qp.data.items()}
        arrays["x_warm"], arrays["y_warm"] = qp.warm_x.copy(), qp.warm_y.copy()
        arrays["x"], arrays["y"] = sol.x.copy(), sol.y.copy()
        self._qps.append((meta, arrays))

    def save(self, path: str | Path) -> Path:
        """Write the recorded QPs (format above); returns the path."""
        path = Path(path)
        out: dict[str, np.ndarray] = {"format": np.array(FORMAT), "version": np.array(VERSION),
                                      "count": np.array(len(self._qps)),
                                      "meta": np.array(json.dumps([m for m, _ in self._qps]))}
        for k, (p_ptr, p_idx, a_ptr, a_idx, n, m) in enumerate(self._shapes):
            out.update({f"shape{k}/P_indptr": p_ptr, f"shape{k}/P_indices": p_idx, f"shape{k}/A_indptr": a_ptr,
                        f"shape{k}/A_indices": a_idx, f"shape{k}/n": np.array(n), f"shape{k}/m": np.array(m)})
        for i, (_, arrays) in enumerate(self._qps):
            out.update({f"qp{i}/{k}": v for k, v in arrays.items()})
        with path.open("wb") as f:
            np.savez_compressed(f, **out)
        return path


class RecordingOsqpQp(OsqpQp):
    """An :class:`OsqpQp` that keeps a copy of its current data and start, and records every solve.

    Every call is passed on to :class:`OsqpQp` unchanged (the solutions are the same bits).
    """

    def __init__(self, recorder: QpRecorder, layout: QpLayout, p_data: np.ndarray, q: np.ndarray,
                 a_data: np.ndarray, l: np.ndarray, u: np.ndarray, *, eps: float, eps_rel: float, polish: bool,
                 rho: float) -> None:
        super().__init__(layout, p_data, q, a_data, l, u, eps=eps, eps_rel=eps_rel, polish=polish, rho=rho)
        self.recorder = recorder
        self.settings = {"eps_abs": float(eps), "eps_rel": float(eps_rel), "rho": float(rho), "polish": bool(polish),
                         "scaling": 0, "adaptive_rho": True}
        self.data = {"P_data": np.array(p_data, dtype=float), "q": np.array(q, dtype=float),
                     "A_data": np.array(a_data, dtype=float), "l": np.array(l, dtype=float),
                     "u": np.array(u, dtype=float)}
        self.warm_x, self.warm_y, self.warm_kind = np.zeros(layout.n), np.zeros(layout.m), "cold"

    def update(self, *, p_data=None, q=None, a_data=None, l=None, u=None) -> None:
        super().update(p_data=p_data, q=q, a_data=a_data, l=l, u=u)
        for key, value in (("P_data", p_data), ("q", q), ("A_data", a_data), ("l", l), ("u", u)):
            if value is not None:
                self.data[key] = np.array(value, dtype=float)

    def warm_start(self, x=None, y=None) -> None:
        super().warm_start(x, y)
        if x is not None:
            self.warm_x = np.array(x, dtype=float)
        if y is not None:
            self.warm_y = np.array(y, dtype=float)
        self.warm_kind = "explicit"

    def solve(self, max_iter: int = MAX_ITER) -> QpSolution:
        sol = super().solve(max_iter)
        self.recorder.add(self, sol, max_iter)
        self.warm_x, self.warm_y, self.warm_kind = sol.x, sol.y, "previous"
        return sol


@contextlib.contextmanager
def recording(recorder: QpRecorder) -> Iterator[QpRecorder]:
    """Make ``recorder`` active: planners' QP shapes first solved inside record their QPs (for good)."""
    global ACTIVE
    previous, ACTIVE = ACTIVE, recorder
    try:
        yield recorder
    finally:
        ACTIVE = previous


def load(path: str | Path) -> list[RecordedQp]:
    """The QPs of a recorded file (format version 1)."""
    with np.load(Path(path), allow_pickle=False) as z:
        if str(z["format"]) != FORMAT or int(z["version"]) != VERSION:
            raise ValueError(f"{path}: not a {FORMAT} version {VERSION} file")
        metas = json.loads(str(z["meta"]))
        shapes: dict[int, tuple] = {}
        out = []
        for i, meta in enumerate(metas):
            k = meta["shape"]
            if k not in shapes:
                n, m = int(z[f"shape{k}/n"]), int(z[f"shape{k}/m"])
                shapes[k] = (n, m, z[f"shape{k}/P_indptr"], z[f"shape{k}/P_indices"],
                             z[f"shape{k}/A_indptr"], z[f"shape{k}/A_indices"])
            n, m, p_ptr, p_idx, a_ptr, a_idx = shapes[k]
            g = lambda name: z[f"qp{i}/{name}"]   # noqa: E731
            out.append(RecordedQp(
                P=sp.csc_matrix((g("P_data"), p_idx, p_ptr), shape=(n, n)), q=g("q"),
                A=sp.csc_matrix((g("A_data"), a_idx, a_ptr), shape=(m, n)), l=g("l"), u=g("u"),
                x_warm=g("x_warm"), y_warm=g("y_warm"), x=g("x"), y=g("y"), meta=meta))
        return out
