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

from ..common import _checks
from ..phy import signal
from ..phy.nr import C, PAPER
from . import correlogram

TOA_METHODS = ("peak", "first_path")
#: a relaxation whose R_1 exceeds ‖p − b_1‖ by more than this (m) is flagged as not tight
TIGHTNESS_TOL_M = 0.5
#: a Gauss–Newton polish that moves the fix farther than this (m) from the convex solution is rejected and flagged
MAX_POLISH_MOVE_M = 100.0
#: the Gauss-Newton polish stops once its step is shorter than this (m): the fix then depends on where the convex
#: solve left it by up to about this much, and the convex solver's last digits differ between CPUs
POLISH_STOP_STEP_M = 1e-6
#: two computations of one OTDoA fix (and of a DPE fix centred on it) agree within this (m) on any two CPUs: the
#: polish's end follows where the convex solve left it, whose last digits differ between CPUs (measured: 3e-8 m in
#: fig10-pr-los-otdoa's trial 1188 between the machine that computed the results store and another, the DPE fix
#: centred on it moving with it).  Moving the polish's start by 3e-8 m moved its end by up to 2.7 µm over 1000
#: simulated 4-BS fixes (median 4e-14 m), hence 10 µm: still 1000 times below the book's centimetres
POSITION_ATOL_M = 10 * POLISH_STOP_STEP_M


# ---- ToA ------------------------------------------------------------------------------------------------------------

def toa(y, prs, method: str = "first_path", upsample: int = 8, threshold_db: float = -10.0,
        max_lead_samples: int = 64, num=PAPER) -> jax.Array:
    """ToA of each BS from its LS CIR estimate (the correlation of eq. (10) with a one-tap window).

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples and pilots of the M links.
    method : str
        "first_path" (the default, the book's detector): the first grid point, at most ``max_lead_samples`` samples
        before the maximum of ``|ĥ(τ)|²`` on the T_s/upsample grid, within ``threshold_db`` of it, then the local
        maximum that follows it; "peak" (the paper's reading, which fails under NLoS): that maximum itself.  Both
        refine with a parabola through the chosen grid point and its two neighbours.
    upsample : int
        Grid points per sample T_s, 1 to 256.
    threshold_db : float
        The first path's threshold relative to the peak, dB, -60 to -0.1.
    max_lead_samples : int
        How far before the peak the first path may lie, samples, 1 to N/2.
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    float (M,)
        ToAs, seconds, in [-N T_s / 2, N T_s / 2) (the correlation is periodic with period N T_s = 1/Δf).

    Raises
    ------
    ValueError
        When the shapes do not match or a parameter is out of its range.
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
    """``toa`` from the LS spectrum, unvalidated and traceable (the Monte Carlo engine's entry point).

    Parameters
    ----------
    g : complex (M, N)
        The LS spectrum (``correlogram.ls_spectrum``).
    method, upsample, threshold_db, max_lead_samples
        As for ``toa``.
    ts : float
        The sample period T_s, seconds.
    dtype : numpy dtype
        The correlogram's (the benchmark compares two); default ``correlogram.GRID_DTYPE``.

    Returns
    -------
    float (M,)
        ToAs, seconds.
    """
    _checks.require_x64()
    e = correlogram.energy_grid(g.astype(dtype), 1, upsample)  # (M, N·U): |ĥ(j T_s/U)|² · N
    return jax.vmap(lambda row: toa_row(row, method, upsample, threshold_db, max_lead_samples, ts))(e)


def toa_row(e, method, upsample, threshold_db, max_lead_samples, ts):
    """The ToA of one link from its energy grid (``toa_from_spectrum``, traceable).

    Parameters
    ----------
    e : float (N·U,)
        ``|ĥ|²`` on the grid of T_s/U, periodic (``correlogram.energy_grid``).
    method, upsample, threshold_db, max_lead_samples, ts
        As for ``toa_from_spectrum``.

    Returns
    -------
    float
        The ToA, seconds, in [-N T_s / 2, N T_s / 2).
    """
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
    """An OTDoA fix.

    Attributes
    ----------
    xyz : float (3,)
        The fix, metres.
    ok : bool
        Whether to trust it.
    reason : str
        Why not, when ``ok`` is False.
    gap_m : float
        R_1 − ‖p − b_1‖ of the convex solution, metres (0 when the relaxation is tight).
    residual_m : float
        The RMS range-difference residual at the fix, metres.
    polish_rejected : bool
        The polish moved farther than ``MAX_POLISH_MOVE_M`` and the convex solution was kept (``ok`` is then False).
    """

    xyz: np.ndarray
    ok: bool
    reason: str
    gap_m: float
    residual_m: float
    polish_rejected: bool = False


#: base stations closer than this (metres) are at one place for ``check_geometry``
SAME_PLACE_M = 1e-3


def check_geometry(bs_xyz) -> np.ndarray:
    """Validate base-station positions for a 2-D fix: M ≥ 3, finite, each at its own place (``SAME_PLACE_M`` apart),
    not all on one line (in plan view).

    Parameters
    ----------
    bs_xyz : float (M, 3)
        Base-station positions, metres.

    Returns
    -------
    float (M, 3)
        The positions, as a float64 array.

    Raises
    ------
    ValueError
        When they are not (M, 3), fewer than 3, not finite, two at one place, or collinear in plan view.
    """
    b = np.asarray(bs_xyz, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 3:
        raise ValueError(f"bs_xyz must be (M, 3) metres, got shape {b.shape}")
    if b.shape[0] < 3:
        raise ValueError(f"OTDoA in 2-D needs at least 3 base stations (2 TDoAs for x, y), got {b.shape[0]}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bs_xyz must be finite")
    close = np.triu(np.linalg.norm(b[:, None] - b[None], axis=-1) < SAME_PLACE_M, 1)
    if close.any():
        i, j = (int(k) for k in np.argwhere(close)[0])
        raise ValueError(f"bs_xyz: base stations {i} and {j} are at one place ({b[i].tolist()} m): their TDoA is 0 "
                         f"whatever the UE's position (give each BS its own site, {SAME_PLACE_M * 1e3:g} mm apart at "
                         "least)")
    d = b[1:, :2] - b[0, :2]
    s = np.linalg.svd(d, compute_uv=False)
    if s[-1] <= 1e-6 * max(s[0], 1.0):
        raise ValueError("the base stations are collinear in plan view: their TDoAs cannot fix a 2-D position")
    return b


class Solver:
    """The SOCP of the module docstring for M BSs, compiled once (DPP) and re-solved with new data by Clarabel.

    ``Solver(m).solve(bs_xyz, toa_s, ue_z)`` → ``Fix``.  DPP makes the map from the parameters to Clarabel's data
    (c, A, b) affine: the constructor reads it from cvxpy once (``Problem.get_problem_data`` at the zero parameter and
    at each unit parameter: the constant and one column per scalar parameter), ``data`` applies it (to the bit: each
    entry is a constant or one parameter times ±1, ``tests/receivers/test_otdoa.py``) and ``solve`` hands the data to cvxpy's
    solving chain, skipping the reduction ``Problem.solve`` repeats, which for a program this small costs more than
    Clarabel's own solve (the engine chapter of the book).  ``solve`` leaves the Parameters alone; ``set_parameters``
    writes them, for a variant of the problem built on them.

    Parameters
    ----------
    n_bs : int
        The number M of BSs, 3 to 1024.
    """

    def __init__(self, n_bs: int):
        import cvxpy as cp  # (cvxpy: 0.9 s to import, only for an OTDoA fix)

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
        """Clarabel's data for parameter values (``parameters``), from the affine map read at construction.

        Parameters
        ----------
        A, beta, ref, dz : float (M−1, 3), (M−1,), (2,) and scalar
            The matrix and β of ``system``, the reference BS's b_1 (x, y) and z − z_1, in its scaled units (1/1000 m).

        Returns
        -------
        dict
            cvxpy's data: c, A (CSC) and b.
        """
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

    def parameters(self, bs_xyz, toa_s, ue_z, weights=None) -> tuple:
        """The values of the problem's Parameters for one fix: ``system`` and the reference BS's position.

        Parameters
        ----------
        bs_xyz : float (M, 3)
            Base-station positions, metres, the reference BS first.
        toa_s : float (M,)
            Their ToAs, seconds.
        ue_z : float
            The known UE height, metres.
        weights : float (M−1,) or None
            w_m, m = 2 … M: equation m of ``system`` (its row of A, its β) times w_m; None: all 1.

        Returns
        -------
        tuple
            (A (M−1, 3), β (M−1,), b_1 (x, y) (2,), z − z_1), as ``data`` takes them, in the scaled units of ``system``
            (1/1000 m).
        """
        b = np.asarray(bs_xyz, dtype=np.float64)
        A, beta = self.system(b, np.asarray(toa_s, dtype=np.float64), ue_z)
        w = np.ones(len(beta)) if weights is None else np.asarray(weights, dtype=np.float64)  # x · 1.0 is x
        return A * w[:, None], beta * w, b[0, :2] / 1000.0, (ue_z - b[0, 2]) / 1000.0

    def set_parameters(self, bs_xyz, toa_s, ue_z) -> None:
        """Write ``parameters`` into the cvxpy Parameters, for a variant of the problem built on them.

        The Fig. 10 chapter solves the squared residual; ``solve`` does not need them set.

        Parameters
        ----------
        bs_xyz, toa_s, ue_z
            As for ``parameters``.
        """
        self._set(self._flat(*self.parameters(bs_xyz, toa_s, ue_z)))

    def system(self, bs_xyz, toa_s, ue_z):
        """(A, β) of the module docstring's linear equations, scaled by 1/1000 m (keeps the solver well conditioned).

        Parameters
        ----------
        bs_xyz : float (M, 3)
            Base-station positions, metres, the reference BS first.
        toa_s : float (M,)
            Their ToAs, seconds.
        ue_z : float
            The known UE height, metres.

        Returns
        -------
        A : float (M−1, 3)
            Rows (2 (b_m − b_1)_x, 2 (b_m − b_1)_y, 2 r_m), m = 2 … M.
        beta : float (M−1,)
            ‖b_m‖² − ‖b_1‖² − r_m² − 2 (b_m − b_1)_z z.
        """
        b = bs_xyz / 1000.0
        z = ue_z / 1000.0
        r = C * (toa_s[1:] - toa_s[0]) / 1000.0
        db = b[1:] - b[0]
        A = np.column_stack([2.0 * db[:, 0], 2.0 * db[:, 1], 2.0 * r])
        beta = (np.sum(b[1:] ** 2, 1) - np.sum(b[0] ** 2) - r**2 - 2.0 * db[:, 2] * z)
        return A, beta

    def solve(self, bs_xyz, toa_s, ue_z: float, polish: bool = True, weights=None) -> Fix:
        """One OTDoA fix: the SOCP, then (with ``polish``) the Gauss–Newton polish.

        Parameters
        ----------
        bs_xyz : float (M, 3)
            Base-station positions, metres, M = ``n_bs``, the reference BS first.
        toa_s : float (M,)
            Their ToAs, seconds (``toa``).
        ue_z : float
            The known UE height, metres.
        polish : bool
            Polish the convex solution with ``gauss_newton``; without it, a relaxation that is not tight is flagged.
        weights : float (M−1,) or None
            w_m > 0 scales range difference m = 2 … M in the SOCP and the polish (``otdoa_nlos.wls_fix``); None: 1.

        Returns
        -------
        Fix
            The fix; a solver failure, a relaxation that is not tight (without polish) or a polish that moves more than
            ``MAX_POLISH_MOVE_M`` from the convex solution is flagged (``ok`` False, the reason; ``polish_rejected``).

        Raises
        ------
        ValueError
            When the geometry is degenerate (``check_geometry``), the shapes do not match ``n_bs`` or a ToA or
            ``ue_z`` is not finite.
        """
        b = check_geometry(bs_xyz)
        t = np.asarray(toa_s, dtype=np.float64)
        if t.shape != (self.n_bs,) or b.shape[0] != self.n_bs:
            raise ValueError(f"expected {self.n_bs} BSs and ToAs, got {b.shape[0]} and {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("toa_s must be finite (a NaN ToA cannot enter a TDoA)")
        _checks.finite("ue_z", ue_z)
        data = self.data(*self.parameters(b, t, ue_z, weights))
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
        ok, reason, rejected = True, "", False
        if polish:
            xy = gauss_newton(b, t, ue_z, p[:2], weights=weights)
            moved = float(np.linalg.norm(xy - p[:2]))
            if moved > MAX_POLISH_MOVE_M:
                # the range-difference cost can fall towards infinity when the TDoAs are inconsistent; keep the
                # convex solution and say so
                ok, rejected, reason = False, True, f"Gauss-Newton moved {moved:.3g} m; kept the convex solution"
            else:
                p[:2] = xy
        elif gap > TIGHTNESS_TOL_M:
            ok, reason = False, f"relaxation not tight (R1 exceeds the range by {gap:.2f} m)"
        if not np.all(np.isfinite(p)):
            ok, reason = False, "non-finite fix"
        res = _rd_residual(b, t, ue_z, p[:2])
        return Fix(p, ok, reason, gap, float(np.sqrt(np.mean(res**2))), rejected)


def _rd_residual(b, t, ue_z, xy):
    p = np.array([xy[0], xy[1], ue_z])
    d = np.linalg.norm(p - b, axis=1)
    return (d[1:] - d[0]) - C * (t[1:] - t[0])


def gauss_newton(bs_xyz, toa_s, ue_z, xy0, iters: int = 10, weights=None) -> np.ndarray:
    """Minimise Σ_m w_m² (‖p − b_m‖ − ‖p − b_1‖ − r_m)² over p_xy by Gauss–Newton (halving a step that raises it).

    Parameters
    ----------
    bs_xyz : float (M, 3)
        Base-station positions, metres, the reference BS first.
    toa_s : float (M,)
        Their ToAs, seconds.
    ue_z : float
        The known UE height, metres.
    xy0 : float (2,)
        The starting point, metres.
    iters : int
        At most this many steps; it stops earlier once a step is shorter than ``POLISH_STOP_STEP_M`` or when no
        halved step lowers the cost.
    weights : float (M−1,) or None
        w_m, m = 2 … M; None: all 1 (the paper's polish, to the bit: x · 1.0 is x).

    Returns
    -------
    float (2,)
        The polished (x, y), metres.
    """
    b = np.asarray(bs_xyz, dtype=np.float64)
    t = np.asarray(toa_s, dtype=np.float64)
    w, xy = np.ones(len(b) - 1) if weights is None else np.asarray(weights, dtype=np.float64), np.array(xy0, float)
    cost = np.sum((w * _rd_residual(b, t, ue_z, xy)) ** 2)
    for _ in range(iters):
        p = np.array([xy[0], xy[1], ue_z])
        u = (p - b)[:, :2] / np.maximum(np.linalg.norm(p - b, axis=1), 1e-9)[:, None]
        J = w[:, None] * (u[1:] - u[0])
        r = w * _rd_residual(b, t, ue_z, xy)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        for _ in range(20):
            new = np.sum((w * _rd_residual(b, t, ue_z, xy + step)) ** 2)
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
    """One OTDoA fix (convenience: builds a ``Solver`` for this M; reuse a Solver for many fixes).

    Parameters
    ----------
    bs_xyz, toa_s, ue_z, polish
        As for ``Solver.solve``.

    Returns
    -------
    Fix
        The fix, flagged as ``Solver.solve`` flags it.

    Raises
    ------
    ValueError
        As ``Solver.solve`` raises it.
    """
    _checks.require_x64()
    b = check_geometry(bs_xyz)
    return Solver(b.shape[0]).solve(b, toa_s, ue_z, polish)
