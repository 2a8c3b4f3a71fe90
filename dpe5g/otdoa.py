"""OTDoA baseline (Section IV-B): ToA per BS from the same received signals the DPE sees, TDoA against a reference
BS, and the position from a convex (second-order-cone) program solved with cvxpy + Clarabel.

Two steps, as a two-step receiver works:

1. ``toa`` — the ToA of each BS from its LS CIR estimate (the same correlation as eq. (10) with a one-tap window):
   the strongest peak ("peak") or the first arrival within ``threshold_db`` of it ("first_path"), refined between
   grid points by a parabola through the three grid values around it.
2. ``solve`` — with r_m = c (τ_m − τ_1) the range differences to the reference BS 1 and R_1 = ‖p − b_1‖,
   ‖p − b_m‖ = R_1 + r_m.  Squaring and subtracting the reference's equation gives equations linear in
   θ = (x, y, R_1):  2 (b_m − b_1)_xy · p_xy + 2 r_m R_1 = ‖b_m‖² − ‖b_1‖² − r_m² − 2 (b_m − b_1)_z z,
   (z the known UE height).  The non-convex R_1 = ‖p − b_1‖ is relaxed to the cone R_1 ≥ ‖p − b_1‖, giving the SOCP
   minimise ‖A θ − β‖  subject to ‖(x − x_1, y − y_1, z − z_1)‖ ≤ R_1,
   written with cvxpy Parameters (A, β, b_1, z − z_1) so the problem is DPP and compiles once.  An optional
   Gauss–Newton polish then minimises the range-difference residuals Σ (‖p − b_m‖ − ‖p − b_1‖ − r_m)².

Degenerate input (fewer than 3 BSs, collinear BSs, NaN ToAs) raises ``ValueError``; a solver failure, a relaxation
that is not tight (without polish) or a polish that runs away from the convex solution is returned as a flagged
solution (``ok`` False with the reason), never silently.
Units: seconds, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks, correlogram, signal
from .nr import C, PAPER

TOA_METHODS = ("peak", "first_path")
#: a relaxation whose R_1 exceeds ‖p − b_1‖ by more than this (m) is flagged as not tight
TIGHTNESS_TOL_M = 0.5
#: a Gauss–Newton polish that moves the fix farther than this (m) from the convex solution is rejected and flagged
MAX_POLISH_MOVE_M = 100.0
#: the Gauss-Newton polish stops once its step is shorter than this (m): the fix then depends on where the convex
#: solve left it by up to about this much, and the convex solver's last digits differ between CPUs
POLISH_STOP_STEP_M = 1e-6


# ---- ToA ------------------------------------------------------------------------------------------------------------

def toa(y, prs, method: str = "peak", upsample: int = 8, threshold_db: float = -10.0,
        max_lead_samples: int = 64, num=PAPER) -> jax.Array:
    """ToA of each BS in seconds from its LS CIR estimate.  y, prs : complex (M, N).  Returns (M,) in
    [-N T_s / 2, N T_s / 2) (the correlation is periodic with period N T_s = 1/Δf).

    method "peak": the maximum of |ĥ(τ)|² on the T_s/upsample grid; "first_path": the first grid point, at most
    ``max_lead_samples`` samples before that maximum, within ``threshold_db`` (< 0) of it, then the local maximum
    that follows it.  Both refine with a parabola through the chosen grid point and its two neighbours.
    """
    _checks.require_x64()
    y, prs = correlogram.check_inputs(y, prs, 1)
    _checks.one_of("method", method, TOA_METHODS)
    _checks.integer("upsample", upsample, 1, 256)
    _checks.in_range("threshold_db", threshold_db, -60.0, -0.1, "dB")
    _checks.integer("max_lead_samples", max_lead_samples, 1, y.shape[1] // 2)
    g = correlogram.ls_spectrum(signal.demodulate(y), jnp.asarray(prs))
    return toa_from_spectrum(g, method, upsample, float(threshold_db), max_lead_samples, num.sample_period_s)


@partial(jax.jit, static_argnames=("method", "upsample", "max_lead_samples", "dtype"))
def toa_from_spectrum(g, method, upsample, threshold_db, max_lead_samples, ts, dtype=correlogram.GRID_DTYPE):
    """``toa`` from the LS spectrum g (M, N) (``correlogram.ls_spectrum``), unvalidated and traceable (the Monte Carlo
    engine's entry point); ts : T_s in seconds; dtype : of the correlogram (the benchmark compares two).  Returns (M,)
    seconds."""
    _checks.require_x64()
    e = correlogram.energy_grid(g.astype(dtype), 1, upsample)  # (M, N·U): |ĥ(j T_s/U)|² · N
    return jax.vmap(lambda row: toa_row(row, method, upsample, threshold_db, max_lead_samples, ts))(e)


def toa_row(e, method, upsample, threshold_db, max_lead_samples, ts):
    j = e.shape[0]
    k = jnp.argmax(e)
    if method == "first_path":
        lead = max_lead_samples * upsample
        offs = jnp.arange(-lead, 1)
        win = e[jnp.mod(k + offs, j)]
        above = win >= e[k] * 10.0 ** (threshold_db / 10.0)
        first = jnp.argmax(above)  # earliest grid point above the threshold (the peak itself at worst)
        # climb to the local maximum after the first crossing, within one sample
        fwd = jnp.arange(0, upsample + 1)
        seg = e[jnp.mod(k + offs[first] + fwd, j)]
        k = jnp.mod(k + offs[first] + jnp.argmax(seg), j)
    em, e0, ep = e[jnp.mod(k - 1, j)], e[k], e[jnp.mod(k + 1, j)]
    den = em - 2.0 * e0 + ep
    frac = jnp.where(den < 0, 0.5 * (em - ep) / den, 0.0)
    pos = (k + jnp.clip(frac, -0.5, 0.5)) / upsample  # samples
    n = j / upsample
    pos = jnp.where(pos >= n / 2, pos - n, pos)
    return pos * ts


# ---- position -------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Fix:
    """An OTDoA fix: xyz (3,) m; ok: whether to trust it; reason: why not; gap_m: R_1 − ‖p − b_1‖ of the convex
    solution (0 when the relaxation is tight); residual_m: RMS range-difference residual at the fix."""

    xyz: np.ndarray
    ok: bool
    reason: str
    gap_m: float
    residual_m: float


def check_geometry(bs_xyz) -> np.ndarray:
    """Validate BS positions (M, 3) m for a 2-D fix: M ≥ 3, finite, not all on one line (in plan view)."""
    b = np.asarray(bs_xyz, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3:
        raise ValueError(f"bs_xyz must be (M, 3) metres, got shape {b.shape}")
    if b.shape[0] < 3:
        raise ValueError(f"OTDoA in 2-D needs at least 3 base stations (2 TDoAs for x, y), got {b.shape[0]}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bs_xyz must be finite")
    d = b[1:, :2] - b[0, :2]
    s = np.linalg.svd(d, compute_uv=False)
    if s[-1] <= 1e-6 * max(s[0], 1.0):
        raise ValueError("the base stations are collinear in plan view: their TDoAs cannot fix a 2-D position")
    return b


class Solver:
    """The SOCP of the module docstring for M BSs, compiled once (DPP) and re-solved with new data.

    ``Solver(m).solve(bs_xyz, toa_s, ue_z)`` → ``Fix``.  Clarabel is the solver.

    cvxpy compiles the problem once; each solve then needs Clarabel's data (c, A, b) at the new parameter values.
    ``Problem.solve`` recomputes them through cvxpy's reduction chain, which for a program this small costs more than
    Clarabel's own solve (``benchmarks/bench_engine.py`` times both).  DPP makes the map from the parameters to the
    data affine, so the constructor reads it from cvxpy once — ``Problem.get_problem_data`` at the zero parameter
    and at each unit parameter gives the constant and one column per scalar parameter — and ``solve`` applies it and
    hands the data to cvxpy's solving chain (``SolvingChain.solve_via_data``, then ``Problem.unpack_results``: the
    route ``get_problem_data``'s documentation gives), which reads the solution back into ``theta``.  Each entry of
    this program's data is a constant or one parameter times ±1, so the map gives cvxpy's data to the bit and the
    same fixes (``tests/test_otdoa.py`` compares both with cvxpy's own path).  ``solve`` leaves the Parameters
    alone; ``set_parameters`` writes them, for a variant of the problem built on them.
    """

    def __init__(self, n_bs: int):
        import cvxpy as cp

        self.n_bs = _checks.integer("n_bs", n_bs, 3, 1024)
        self.A = cp.Parameter((n_bs - 1, 3))
        self.beta = cp.Parameter(n_bs - 1)
        self.ref = cp.Parameter(2)  # (x_1, y_1)
        self.dz = cp.Parameter()  # z − z_1
        self.theta = cp.Variable(3)  # (x, y, R_1)
        cone = cp.norm(cp.hstack([self.theta[0] - self.ref[0], self.theta[1] - self.ref[1], self.dz])) <= self.theta[2]
        self.problem = cp.Problem(cp.Minimize(cp.norm(self.A @ self.theta - self.beta)), [cone])
        if not self.problem.is_dpp():
            raise RuntimeError("the OTDoA problem is not DPP")
        self._cp = cp
        self._params = (self.A, self.beta, self.ref, self.dz)
        n = sum(int(np.prod(q.shape)) for q in self._params)
        probes = [self._cvxpy_data(np.eye(n)[k]) for k in range(n)]
        self._template, self._chain, self._inverse = self._cvxpy_data(np.zeros(n), full=True)
        base = self._template
        self._structure = (base["A"].indices.copy(), base["A"].indptr.copy(), base["A"].shape)
        if not all(np.array_equal(pr["A"].indices, self._structure[0])
                   and np.array_equal(pr["A"].indptr, self._structure[1]) for pr in probes):
            raise RuntimeError("cvxpy's data for the OTDoA problem changed its sparsity with the parameters")
        value = lambda d, key: d[key].data if key == "A" else d[key]
        cols = {key: (value(base, key).copy(), np.stack([value(pr, key) - value(base, key) for pr in probes], 1))
                for key in ("c", "b", "A")}
        self._map = cols

    def _set(self, v):
        """Write the flat parameter vector v (A row-major, β, b_1 xy, z − z_1) into the cvxpy Parameters."""
        k = 0
        for q in self._params:
            size = int(np.prod(q.shape))
            q.value = v[k:k + size].reshape(q.shape) if q.shape else float(v[k])
            k += size

    def _cvxpy_data(self, v, full: bool = False):
        """cvxpy's Clarabel data at parameters v (and its solving chain and inverse data if ``full``)."""
        self._set(v)
        data, chain, inverse = self.problem.get_problem_data(self._cp.CLARABEL, solver_opts={})
        return (data, chain, inverse) if full else data

    def data(self, A, beta, ref, dz) -> dict:
        """Clarabel's data for parameters (A (M−1, 3), β (M−1,), b_1 (2,), z − z_1) (``parameters``), in the scaled
        units of ``system``: cvxpy's dict with c, A (CSC) and b from the affine map read at construction."""
        v = self._flat(A, beta, ref, dz)
        out = dict(self._template)
        for key, (b0, cols) in self._map.items():
            val = b0 + cols @ v
            out[key] = val if key != "A" else type(self._template["A"])((val, *self._structure[:2]),
                                                                          shape=self._structure[2])
        return out

    @staticmethod
    def _flat(A, beta, ref, dz) -> np.ndarray:
        """The parameters as one vector, in ``_set``'s order."""
        return np.concatenate([np.ravel(A), np.ravel(beta), np.ravel(ref), [float(dz)]])

    def parameters(self, bs_xyz, toa_s, ue_z) -> tuple:
        """The values (A, β, b_1, z − z_1) of the problem's Parameters for this fix: ``system`` and the reference
        BS's position, in its scaled units (1/1000 m)."""
        b = np.asarray(bs_xyz, dtype=np.float64)
        A, beta = self.system(b, np.asarray(toa_s, dtype=np.float64), ue_z)
        return A, beta, b[0, :2] / 1000.0, (ue_z - b[0, 2]) / 1000.0

    def set_parameters(self, bs_xyz, toa_s, ue_z) -> None:
        """Write ``parameters`` into the cvxpy Parameters, for a variant of the problem built on them (the Fig. 10
        chapter solves the squared residual); ``solve`` does not need them set."""
        self._set(self._flat(*self.parameters(bs_xyz, toa_s, ue_z)))

    def system(self, bs_xyz, toa_s, ue_z):
        """(A, β) of the linear equations, scaled by 1/1000 m (keeps the solver well conditioned)."""
        b = bs_xyz / 1000.0
        z = ue_z / 1000.0
        r = C * (toa_s[1:] - toa_s[0]) / 1000.0
        db = b[1:] - b[0]
        A = np.column_stack([2.0 * db[:, 0], 2.0 * db[:, 1], 2.0 * r])
        beta = (np.sum(b[1:] ** 2, 1) - np.sum(b[0] ** 2) - r**2 - 2.0 * db[:, 2] * z)
        return A, beta

    def solve(self, bs_xyz, toa_s, ue_z: float, polish: bool = True) -> Fix:
        b = check_geometry(bs_xyz)
        t = np.asarray(toa_s, dtype=np.float64)
        if t.shape != (self.n_bs,) or b.shape[0] != self.n_bs:
            raise ValueError(f"expected {self.n_bs} BSs and ToAs, got {b.shape[0]} and {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("toa_s must be finite (a NaN ToA cannot enter a TDoA)")
        _checks.finite("ue_z", ue_z)
        data = self.data(*self.parameters(b, t, ue_z))
        try:
            # no warm start (cvxpy's default): it made a fix depend, by up to a few µm, on the solves before it, so
            # the Monte Carlo's OTDoA fixes depended on its chunking
            sol = self._chain.solve_via_data(self.problem, data, warm_start=False, verbose=False, solver_opts={})
            self.problem.unpack_results(sol, self._chain, self._inverse)
        except self._cp.error.SolverError as exc:
            return Fix(np.full(3, np.nan), False, f"solver error: {exc}", np.nan, np.nan)
        if self.problem.status not in ("optimal", "optimal_inaccurate") or self.theta.value is None:
            return Fix(np.full(3, np.nan), False, f"solver status {self.problem.status}", np.nan, np.nan)
        th = self.theta.value * 1000.0
        p = np.array([th[0], th[1], ue_z])
        gap = float(th[2] - np.linalg.norm(p - b[0]))
        ok, reason = True, ""
        if polish:
            xy = gauss_newton(b, t, ue_z, p[:2])
            moved = float(np.linalg.norm(xy - p[:2]))
            if moved > MAX_POLISH_MOVE_M:
                # the range-difference cost can fall towards infinity when the TDoAs are inconsistent; keep the
                # convex solution and say so
                ok, reason = False, f"Gauss-Newton moved {moved:.3g} m from the convex solution; kept the latter"
            else:
                p[:2] = xy
        elif gap > TIGHTNESS_TOL_M:
            ok, reason = False, f"relaxation not tight (R1 exceeds the range by {gap:.2f} m)"
        if not np.all(np.isfinite(p)):
            ok, reason = False, "non-finite fix"
        res = _rd_residual(b, t, ue_z, p[:2])
        return Fix(p, ok, reason, gap, float(np.sqrt(np.mean(res**2))))


def _rd_residual(b, t, ue_z, xy):
    p = np.array([xy[0], xy[1], ue_z])
    d = np.linalg.norm(p - b, axis=1)
    return (d[1:] - d[0]) - C * (t[1:] - t[0])


def gauss_newton(bs_xyz, toa_s, ue_z, xy0, iters: int = 10) -> np.ndarray:
    """Minimise Σ_m (‖p − b_m‖ − ‖p − b_1‖ − r_m)² over p_xy from xy0 by Gauss–Newton (step halving if the cost
    rises).  Returns xy (2,)."""
    b = np.asarray(bs_xyz, dtype=np.float64)
    t = np.asarray(toa_s, dtype=np.float64)
    xy = np.asarray(xy0, dtype=np.float64).copy()
    cost = np.sum(_rd_residual(b, t, ue_z, xy) ** 2)
    for _ in range(iters):
        p = np.array([xy[0], xy[1], ue_z])
        u = (p - b)[:, :2] / np.maximum(np.linalg.norm(p - b, axis=1), 1e-9)[:, None]
        J = u[1:] - u[0]
        r = _rd_residual(b, t, ue_z, xy)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        for _ in range(20):
            new = np.sum(_rd_residual(b, t, ue_z, xy + step) ** 2)
            if new <= cost:
                break
            step = step / 2
        else:
            break
        xy, cost = xy + step, new
        if np.linalg.norm(step) < POLISH_STOP_STEP_M:
            break
    return xy


def solve(bs_xyz, toa_s, ue_z: float, polish: bool = True) -> Fix:
    """One OTDoA fix (convenience: builds a ``Solver`` for this M; reuse a Solver for many fixes)."""
    _checks.require_x64()
    b = check_geometry(bs_xyz)
    return Solver(b.shape[0]).solve(b, toa_s, ue_z, polish)
