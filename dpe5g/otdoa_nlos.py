"""The NLoS-aware OTDoA receiver (ours, beyond the paper): per-link ToA variances, a weighted fix, and NLoS links
detected and excluded by a residual test (RAIM-style fault detection and exclusion).

The paper's OTDoA baseline (``otdoa``) fits every detected first path with equal weight.  This receiver:

1. ``link_sigma_m`` — each link's first-path ToA (``otdoa.toa``'s detector) and its standard deviation in metres,
   from the link's own correlogram only (eq. (O1) of the NLoS chapter):

       σ_m² = σ_CRB,m² + (c / B)² / 12 + c² (τ̂_peak,m − τ̂_first,m)² / 12,     σ_CRB,m = c √3 / (√2 π B √SNR̂_m),

   σ_CRB the Cramér–Rao bound of a ToA over a flat band B (the pilots' occupied bandwidth; RMS bandwidth B/√12)
   at the link's post-correlation SNR SNR̂ = (peak − floor) / floor of its correlogram, the noise floor its mean over
   the half of the period farthest from the peak (at least 8 µs from it with the paper's numerology, where no path of a TDL
   channel, excess delay included, arrives); the second, a uniform spread over one resolution cell 1/B: paths
   closer than that are not resolved, and a TDL channel's taps lie within a few cells of each other (the CRB alone,
   millimetres at Fig. 10's SNRs, made the test flag every four-LoS trial of Fig. 10 under the UMi delay); the
   third, a uniform spread over
   the span between the first path and the strongest peak, grows when multipath (NLoS: a weak or absent direct path)
   separates them.  No truth enters: neither the SNR the experiment set, nor the LoS state.
2. ``wls_fix`` — the weighted least squares of the ToAs over (x, y, c δt), the UE height known:
   minimise Σ_m (c τ_m − ‖p − b_m‖ − c δt)² / σ_m²  (the TDoA fit with its full covariance, the clock kept
   explicit so that any subset of links is fitted alike), by Gauss–Newton from the SOCP fix of ``otdoa.Solver``.
   Where that cost has no minimum near the links (it keeps falling as the fix runs away from them, which happens
   when the weights trust ToAs that no point fits), a fit that stops short of convergence farther from its start
   than the farthest of its BSs is no fix: the start is kept instead.
3. ``NlosSolver.fix`` — the test statistic T = Σ_m e_m² / σ_m² of the fit is χ² with M − 3 degrees of freedom when
   every ToA is unbiased with the modelled σ.  T above its 1 − ``FALSE_ALARM`` quantile detects an inconsistent set;
   with M − 3 ≥ 2 the link of the largest normalised residual w_m = e_m / √(Q_e)_mm is excluded (Baarda's w-test:
   Q_e = Σ − J (Jᵀ Σ⁻¹ J)⁻¹ Jᵀ is the covariance of the residuals e at the fit, J their Jacobian, Σ = diag σ²; for
   a single biased link it points at that link, and it costs one fit per round where leave-one-out fits cost M),
   then the rest is fitted and tested again; an exclusion is made only while the remaining links can still be
   tested (M − 3 ≥ 1 after it).  With the 4
   nearest BSs (M − 3 = 1) the test detects but cannot identify: it flags the fix and excludes nothing.

Units: seconds, metres.  Bad input raises ``ValueError``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks, correlogram, otdoa, signal
from .nr import C, PAPER

#: the residual test's false-alarm rate: the probability that a set of unbiased ToAs with the modelled σ is flagged
FALSE_ALARM = 0.01
#: Gauss–Newton of ``wls_fix`` stops once its step is shorter than this (m)
WLS_STOP_STEP_M = 1e-6


def sigma_from_grid(e, toa_first_s, toa_peak_s, bandwidth_hz: float) -> np.ndarray:
    """Eq. (O1): each link's ToA standard deviation from its correlogram and its two detectors' ToAs.

    Traceable (the Monte Carlo engine computes it with ``otdoa_nlos``).

    Parameters
    ----------
    e : float (M, J)
        Each link's one-tap correlogram (the energy of ĥ(τ)) on a uniform grid of the period (``correlogram.energy_grid``).
    toa_first_s, toa_peak_s : float (M,)
        The first-path and strongest-peak ToAs, seconds (``otdoa.toa``, "first_path" and "peak").
    bandwidth_hz : float or float (M,)
        B, the pilots' occupied bandwidth, Hz.

    Returns
    -------
    float (M,)
        σ_m, metres.
    """
    spread = C * jnp.abs(jnp.asarray(toa_peak_s) - jnp.asarray(toa_first_s))
    return jnp.sqrt(crb_m(e, bandwidth_hz) ** 2 + (C / bandwidth_hz) ** 2 / 12.0 + spread**2 / 12.0)


def crb_m(e, bandwidth_hz):
    """Eq. (O1)'s first term: the Cramér–Rao bound of a ToA over a flat band at the correlogram's SNR, metres.

    Parameters
    ----------
    e : float (M, J)
        Each link's one-tap correlogram on a uniform grid of the period.
    bandwidth_hz : float or float (M,)
        B, Hz.

    Returns
    -------
    float (M,)
        c √3 / (√2 π B √SNR̂), SNR̂ the peak over the mean of the half period opposite it, less one.
    """
    e = jnp.asarray(e, dtype=jnp.float64)
    floor = noise_floor(e)
    snr = jnp.maximum(jnp.max(e, axis=-1) - floor, 1e-300) / floor
    return C * jnp.sqrt(3.0) / (jnp.sqrt(2.0) * jnp.pi * bandwidth_hz * jnp.sqrt(snr))


def noise_floor(e) -> jax.Array:
    """A correlogram's noise floor: its mean over the half of the period opposite its peak (traceable).

    With the paper's numerology that half is at least 8 µs from the peak, where no path of a TDL channel, excess delay
    included, arrives.

    Parameters
    ----------
    e : float (..., J)
        Correlograms on a uniform grid of the period.

    Returns
    -------
    float (...)
        The floor, in the correlogram's units.
    """
    e = jnp.asarray(e, dtype=jnp.float64)
    n = e.shape[-1]
    k = jnp.argmax(e, axis=-1)
    far = jnp.mod(k[..., None] + n // 4 + jnp.arange(n // 2), n)  # the half period opposite the peak
    return jnp.mean(jnp.take_along_axis(e, far, axis=-1), axis=-1)


def sigma_of_spectrum(g, prs, toa_first_s, toa_peak_s, upsample: int, scs_hz: float):
    """Eq. (O1) from the links' LS spectra: ``sigma_from_grid`` on their one-tap correlograms, B each link's occupied
    bandwidth (its non-zero pilots times Δf).  Traceable (the Monte Carlo engine's ``otdoa_nlos``).

    Parameters
    ----------
    g : complex (M, N)
        The LS spectra (``correlogram.ls_spectrum``).
    prs : complex (M, N)
        The pilots.
    toa_first_s, toa_peak_s : float (M,)
        The two detectors' ToAs, seconds.
    upsample : int
        Grid points per sample of the correlogram.
    scs_hz : float
        Δf, Hz.

    Returns
    -------
    float (M,)
        σ_m, metres.
    """
    e = correlogram.energy_grid(g.astype(correlogram.GRID_DTYPE), 1, upsample)
    return sigma_from_grid(e, toa_first_s, toa_peak_s, jnp.count_nonzero(prs, axis=-1) * scs_hz)


def link_sigma_m(y, prs, upsample: int = 8, threshold_db: float = -10.0, max_lead_samples: int = 64,
                 num=PAPER) -> tuple[np.ndarray, np.ndarray]:
    """Each link's first-path ToA and its standard deviation (eq. (O1)), from the received signal only.

    Parameters
    ----------
    y, prs : complex (M, N)
        Received samples and pilots of the M links.
    upsample, threshold_db, max_lead_samples, num
        As for ``otdoa.toa``.

    Returns
    -------
    toa_s : float (M,)
        First-path ToAs, seconds (``otdoa.toa``).
    sigma_m : float (M,)
        Their standard deviations, metres.

    Raises
    ------
    ValueError
        As ``otdoa.toa``.
    """
    _checks.require_x64()
    y, prs = correlogram.check_inputs(y, prs, 1)
    _checks.integer("upsample", upsample, 1, 256)
    _checks.in_range("threshold_db", threshold_db, -60.0, -0.1, "dB")
    _checks.integer("max_lead_samples", max_lead_samples, 1, y.shape[1] // 2)
    g = correlogram.ls_spectrum(signal.demodulate(y), jnp.asarray(prs))
    first, sigma = _toa_and_sigma(g, jnp.asarray(prs), upsample, float(threshold_db), max_lead_samples,
                                  num.sample_period_s, num.scs_hz)
    return np.asarray(first), np.asarray(sigma)


@partial(jax.jit, static_argnames=("upsample", "max_lead_samples"))
def _toa_and_sigma(g, prs, upsample, threshold_db, max_lead_samples, ts, scs_hz):
    """The first-path ToA and σ of each link (both detectors by ``otdoa.toa_row``), in one program."""
    e = correlogram.energy_grid(g.astype(correlogram.GRID_DTYPE), 1, upsample)
    first, peak = [jax.vmap(lambda row, m=method: otdoa.toa_row(row, m, upsample, threshold_db, max_lead_samples,
                                                                ts))(e) for method in ("first_path", "peak")]
    return first, sigma_of_spectrum(g, prs, first, peak, upsample, scs_hz)


def _residual(b, t, ue_z, q):
    """e_m = c τ_m − ‖p − b_m‖ − c δt at q = (x, y, c δt); metres."""
    p = np.array([q[0], q[1], ue_z])
    return C * t - np.linalg.norm(p - b, axis=1) - q[2]


def wls_fix(bs_xyz, toa_s, sigma_m, ue_z: float, xy0, iters: int = 30) -> tuple[np.ndarray, float]:
    """The weighted least-squares fix of step 2 of the module docstring, by Gauss–Newton with step halving.

    Every step lowers the weighted cost.  A fit that stops before its steps shrink below ``WLS_STOP_STEP_M`` (after
    ``iters`` steps, or where no step lowers the cost) farther from xy0 than the farthest BS is from xy0 is running
    away from the links (its cost has no minimum near them), and the start is returned instead: xy0 with its clock
    term and its T.

    Parameters
    ----------
    bs_xyz : float (M, 3)
        Base-station positions, metres, M ≥ 3.
    toa_s : float (M,)
        Their ToAs, seconds (the clock bias included).
    sigma_m : float (M,)
        Their standard deviations, metres, > 0.
    ue_z : float
        The known UE height, metres.
    xy0 : float (2,)
        The start, metres (the clock term starts at the weighted mean of c τ_m − ‖p − b_m‖ there).
    iters : int
        At most this many steps.

    Returns
    -------
    q : float (3,)
        (x, y, c δt), metres.
    statistic : float
        T = Σ_m e_m² / σ_m² at q.
    """
    b, t = np.asarray(bs_xyz, dtype=np.float64), np.asarray(toa_s, dtype=np.float64)
    w = 1.0 / np.asarray(sigma_m, dtype=np.float64)
    q = np.array([xy0[0], xy0[1], 0.0])
    q[2] = np.sum(w**2 * _residual(b, t, ue_z, q)) / np.sum(w**2)
    cost = np.sum((w * _residual(b, t, ue_z, q)) ** 2)
    start, converged = (q.copy(), float(cost)), False
    for _ in range(iters):
        p = np.array([q[0], q[1], ue_z])
        u = (p - b)[:, :2] / np.maximum(np.linalg.norm(p - b, axis=1), 1e-9)[:, None]
        J = -np.column_stack([u, np.ones(len(b))])  # ∂e/∂q
        step = np.linalg.lstsq(w[:, None] * J, -w * _residual(b, t, ue_z, q), rcond=None)[0]
        for _ in range(30):
            new = np.sum((w * _residual(b, t, ue_z, q + step)) ** 2)
            if new <= cost:
                break
            step = step / 2
        else:  # no step lowers the cost (it is flat to the last bit, as far out on its way to infinity)
            break
        q, cost = q + step, new
        if np.linalg.norm(step) < WLS_STOP_STEP_M:
            converged = True
            break
    reach = np.max(np.linalg.norm(b[:, :2] - start[0][:2], axis=1))
    if not converged and np.linalg.norm(q[:2] - start[0][:2]) > reach:
        return start  # still on its way when it stopped, and past every BS: running away from the links
    return q, float(cost)


def normalised_residuals(bs_xyz, toa_s, sigma_m, ue_z: float, q) -> np.ndarray:
    """Baarda's w-test statistics w_m = e_m / √(Q_e)_mm of the weighted fit at q (module docstring, step 3).

    Parameters
    ----------
    bs_xyz, toa_s, sigma_m, ue_z
        As for ``wls_fix``.
    q : float (3,)
        The fit (x, y, c δt), metres (``wls_fix``).

    Returns
    -------
    float (M,)
        Standard normal for each link when every ToA is unbiased with its σ.
    """
    b, s = np.asarray(bs_xyz, dtype=np.float64), np.asarray(sigma_m, dtype=np.float64)
    p = np.array([q[0], q[1], ue_z])
    u = (p - b)[:, :2] / np.maximum(np.linalg.norm(p - b, axis=1), 1e-9)[:, None]
    J = -np.column_stack([u, np.ones(len(b))])
    Jw = J / s[:, None]
    q_e = np.diag(s**2) - J @ np.linalg.pinv(Jw.T @ Jw) @ J.T  # pinv: links left in a line leave it singular
    e = _residual(b, np.asarray(toa_s, dtype=np.float64), ue_z, q)
    return e / np.sqrt(np.maximum(np.diag(q_e), 1e-300))


@dataclass(frozen=True)
class NlosFix:
    """A fix of the NLoS-aware OTDoA receiver.

    Attributes
    ----------
    xyz : float (3,)
        The fix, metres (z the known UE height).
    clock_m : float
        c δt of the fit, metres.
    statistic : float
        T of the final fit (χ² with ``dof`` degrees of freedom for unbiased ToAs).
    dof : int
        Links used minus 3.
    threshold : float
        T's 1 − ``FALSE_ALARM`` quantile at ``dof`` (NaN where dof = 0: no test).
    detected : bool
        The full set of links failed the test.
    excluded : tuple of int
        The links excluded, indices into the input, in the order of exclusion.
    consistent : bool
        The final set passes the test (False also where it could not be tested).
    ok : bool
        The start was found (False with ``reason`` otherwise).
    reason : str
        Why not ok.
    """

    xyz: np.ndarray
    clock_m: float
    statistic: float
    dof: int
    threshold: float
    detected: bool
    excluded: tuple
    consistent: bool
    ok: bool
    reason: str


def threshold(dof: int, false_alarm: float = FALSE_ALARM) -> float:
    """The residual test's threshold: the 1 − ``false_alarm`` quantile of χ² with ``dof`` degrees of freedom.

    Parameters
    ----------
    dof : int
        Degrees of freedom, ≥ 1 (NaN for 0: nothing to test).
    false_alarm : float
        In (0, 0.5].

    Returns
    -------
    float
    """
    from scipy.stats import chi2

    return float("nan") if dof < 1 else float(chi2.isf(false_alarm, dof))


class NlosSolver:
    """The NLoS-aware OTDoA receiver of the module docstring; one ``otdoa.Solver`` per number of links, kept.

    Parameters
    ----------
    false_alarm : float
        The residual test's false-alarm rate, 1e-6 to 0.5 (default ``FALSE_ALARM``).
    exclude : bool
        Identify and exclude inconsistent links (default); False: the weighted fix and the test only.
    """

    def __init__(self, false_alarm: float = FALSE_ALARM, exclude: bool = True):
        self.false_alarm = _checks.in_range("false_alarm", false_alarm, 1e-6, 0.5)
        self.exclude = bool(exclude)
        self._solvers = {}

    def start(self, b, t, ue_z) -> otdoa.Fix:
        """The SOCP fix of ``otdoa.Solver`` without its polish (the start of the weighted fit).

        Parameters
        ----------
        b : float (M, 3)
            Base-station positions, metres.
        t : float (M,)
            ToAs, seconds.
        ue_z : float
            The known UE height, metres.

        Returns
        -------
        otdoa.Fix
        """
        m = len(b)
        if m not in self._solvers:
            self._solvers[m] = otdoa.Solver(m)
        return self._solvers[m].solve(b, t, ue_z, polish=False)

    def fix(self, bs_xyz, toa_s, sigma_m, ue_z: float) -> NlosFix:
        """One fix: weighted fit, residual test and, where the links allow, exclusion (module docstring).

        Parameters
        ----------
        bs_xyz : float (M, 3)
            Base-station positions, metres, M ≥ 3 (``otdoa.check_geometry``).
        toa_s : float (M,)
            ToAs, seconds, finite.
        sigma_m : float (M,)
            Their standard deviations, metres, finite and > 0 (``link_sigma_m``).
        ue_z : float
            The known UE height, metres.

        Returns
        -------
        NlosFix

        Raises
        ------
        ValueError
            On degenerate geometry, shapes that differ, or a ToA, σ or height that is not finite (σ ≤ 0).
        """
        b = otdoa.check_geometry(bs_xyz)
        t, s = np.asarray(toa_s, dtype=np.float64), np.asarray(sigma_m, dtype=np.float64)
        if t.shape != (len(b),) or s.shape != (len(b),):
            raise ValueError(f"toa_s and sigma_m must be ({len(b)},) like bs_xyz, got {t.shape} and {s.shape}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(s)) and np.all(s > 0)):
            raise ValueError("toa_s must be finite and sigma_m finite and > 0 (metres)")
        _checks.finite("ue_z", ue_z)
        first = self.start(b, t, ue_z)
        if not np.all(np.isfinite(first.xyz)):
            return NlosFix(np.full(3, np.nan), np.nan, np.nan, len(b) - 3, np.nan, False, (), False, False,
                           first.reason)
        active = list(range(len(b)))
        q, stat = wls_fix(b, t, s, ue_z, first.xyz[:2])
        detected = len(b) > 3 and stat > threshold(len(b) - 3, self.false_alarm)
        excluded = []
        while self.exclude and len(active) - 3 >= 2 and stat > threshold(len(active) - 3, self.false_alarm):
            k = active[int(np.argmax(np.abs(normalised_residuals(b[active], t[active], s[active], ue_z, q))))]
            active.remove(k)
            excluded.append(k)
            q, stat = wls_fix(b[active], t[active], s[active], ue_z, q[:2])
        dof = len(active) - 3
        thr = threshold(dof, self.false_alarm)
        return NlosFix(np.array([q[0], q[1], ue_z]), float(q[2]), stat, dof, thr, bool(detected), tuple(excluded),
                       bool(dof >= 1 and stat <= thr), True, "")


def chunk_fixes(m_values, bs_xyz, toa_s, sigma_m, ue_xyz, bs_index, solver: NlosSolver) -> dict:
    """The receiver on a Monte Carlo chunk's first-path ToAs, for every SNR and M (the engine's ``otdoa_nlos``).

    Parameters
    ----------
    m_values : tuple of int
        The M values (the M nearest links of each trial).
    bs_xyz : float (B, 3)
        The deployment's base stations, metres.
    toa_s : float (T, S, I)
        First-path ToAs of the I nearest links, seconds.
    sigma_m : float (T, S, I)
        Their standard deviations, metres (eq. (O1)).
    ue_xyz : float (T, 3)
        The true UE positions, metres: their heights (known to the receiver) and the errors.
    bs_index : int (T, I)
        The nearest BSs' indices into ``bs_xyz``.
    solver : NlosSolver
        The receiver.

    Returns
    -------
    dict
        ``results.Results``'s NLoS-aware fields: "otdoa_sigma_m" (T, S, I); "otdoa_nlos_xyz" (T, S, J, 3) and
        "otdoa_nlos_error_m" (T, S, J), metres; "otdoa_nlos_detected" (T, S, J); "otdoa_nlos_excluded" (T, S, J, I).
    """
    n_t, n_s, n_i = toa_s.shape
    n_j = len(m_values)
    xyz = np.full((n_t, n_s, n_j, 3), np.nan)
    detected = np.zeros((n_t, n_s, n_j), dtype=bool)
    excluded = np.zeros((n_t, n_s, n_j, n_i), dtype=bool)
    for t in range(n_t):
        for j, m in enumerate(m_values):
            bs = bs_xyz[bs_index[t, :m]]
            for s in range(n_s):
                f = solver.fix(bs, toa_s[t, s, :m], sigma_m[t, s, :m], float(ue_xyz[t, 2]))
                xyz[t, s, j], detected[t, s, j] = f.xyz, f.detected
                excluded[t, s, j, list(f.excluded)] = True
    err = np.linalg.norm(xyz[..., :2] - ue_xyz[:, None, None, :2], axis=-1)
    return {"otdoa_sigma_m": np.asarray(sigma_m), "otdoa_nlos_xyz": xyz, "otdoa_nlos_error_m": err,
            "otdoa_nlos_detected": detected, "otdoa_nlos_excluded": excluded}
