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
2. ``wls_fix`` — the paper's OTDoA fit, weighted: ``otdoa.Solver.solve`` (the SOCP on the range differences to a
   reference link, its Gauss–Newton polish, and its acceptance: a polish that moves farther than
   ``otdoa.MAX_POLISH_MOVE_M`` keeps the convex solution, the *fallback*), the reference the most trusted link (the
   smallest σ; among equals the first, the nearest BS, as in ``otdoa``) and range difference m weighted by its
   variance (``difference_weights``): minimise Σ_m (‖p − b_m‖ − ‖p − b_ref‖ − r_m)² · 2 σ_ref² / (σ_ref² + σ_m²),
   the UE height known.  The correlation the shared reference puts between the differences (at most 1/2, the
   smaller the more trusted the reference) is left out, as the paper's fit leaves it out (weighting by the full
   covariance instead, with the same steps and acceptance, did worse in the city and the TDL model, at p90).  With
   equal σ every weight is 1 to the bit and the fix is the paper's.  (The fit it replaces, the ToAs' weighted least
   squares over (x, y, c δt) by its own Gauss–Newton from the SOCP fix, was not the paper's fit with equal σ: its
   cost fitted the clock where the paper's differences it away, it stopped after 30 steps, and it kept any fit short
   of every BS; in the ray-traced city its 90 % error with equal σ was 159.5 m against the paper's 71.9 m.)
3. ``NlosSolver.fix`` — the residuals ê of the ToAs' weighted least squares over (x, y, c δt), linearised at the fix
   (``gls_residuals``; at that least squares' minimum they are its residuals), give T = Σ_m ê_m² / σ_m², χ² with
   M − 3 degrees of freedom when every ToA is unbiased with the modelled σ, whichever unbiased fit supplied the
   point.  T above its 1 − ``FALSE_ALARM`` quantile detects an inconsistent set;
   with M − 3 ≥ 2 the link of the largest normalised residual w_m = ê_m / √(Q_e)_mm is excluded (Baarda's w-test:
   Q_e = Σ − J (Jᵀ Σ⁻¹ J)⁻¹ Jᵀ is the covariance of ê, J the Jacobian of the ToAs in (x, y, c δt), Σ = diag σ²; for
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

from ..common import _checks
from ..phy import signal
from ..phy.nr import C, PAPER
from . import correlogram, otdoa

#: the residual test's false-alarm rate: the probability that a set of unbiased ToAs with the modelled σ is flagged
FALSE_ALARM = 0.01


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


def check_links(bs_xyz, toa_s, sigma_m, ue_z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate one fix's links: the BSs (``otdoa.check_geometry``), a finite ToA and a finite σ > 0 per BS, a
    finite UE height.

    Parameters
    ----------
    bs_xyz, toa_s, sigma_m, ue_z
        As for ``wls_fix``.

    Returns
    -------
    bs_xyz, toa_s, sigma_m : numpy.ndarray
        As float64 arrays.

    Raises
    ------
    ValueError
        Naming the parameter that is not so.
    """
    b = otdoa.check_geometry(bs_xyz)
    t, s = np.asarray(toa_s, dtype=np.float64), np.asarray(sigma_m, dtype=np.float64)
    if t.shape != (len(b),) or s.shape != (len(b),):
        raise ValueError(f"toa_s and sigma_m must be ({len(b)},) like bs_xyz, got {t.shape} and {s.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("toa_s must be finite (seconds)")
    _positive_sigma(s)
    _checks.finite("ue_z", ue_z)
    return b, t, s


def _positive_sigma(s: np.ndarray) -> None:
    if not (s.ndim == 1 and len(s) and np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ValueError(f"sigma_m must be a non-empty (M,) array, finite and > 0 (metres), got {s!r:.80}")


def difference_weights(sigma_m) -> tuple[np.ndarray, np.ndarray]:
    """The weighted fit's reference link and the weights of its range differences (module docstring, step 2).

    Parameters
    ----------
    sigma_m : float (M,)
        The links' σ, metres, > 0.

    Returns
    -------
    order : int (M,)
        The links, the reference first (the smallest σ, the first of equals), the others in their order.
    weights : float (M−1,)
        w_m = √(2 σ_ref² / (σ_ref² + σ_m²)) of the others, in that order: 1 to the bit where σ_m = σ_ref.
    """
    s = np.asarray(sigma_m, dtype=np.float64)
    _positive_sigma(s)
    ref = int(np.argmin(s))
    order = np.r_[ref, np.delete(np.arange(len(s)), ref)]
    v = s[ref] ** 2
    return order, np.sqrt(2.0 * v / (v + s[order[1:]] ** 2))


def wls_fix(bs_xyz, toa_s, sigma_m, ue_z: float, solver=None) -> tuple[np.ndarray, float, otdoa.Fix]:
    """The weighted fix of step 2 of the module docstring: ``otdoa.Solver.solve`` on the links ordered and weighted by
    ``difference_weights``, and its residual test's T (``gls_residuals``).

    With equal σ it is ``otdoa.Solver.solve``'s fix to the bit.  A polish that moves farther than
    ``otdoa.MAX_POLISH_MOVE_M`` keeps the weighted SOCP's solution, as the paper's fit keeps its own (the fallback:
    ``fix.polish_rejected``).

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
    solver : otdoa.Solver or None
        The compiled problem for M links (``NlosSolver.solver``); None: built here.

    Returns
    -------
    q : float (3,)
        (x, y, c δt), metres, c δt the σ⁻²-weighted mean of c τ_m − ‖p − b_m‖ at the fix; NaN where the SOCP failed.
    statistic : float
        T = Σ_m ê_m² / σ_m² at q (``gls_residuals``); NaN where the SOCP failed.
    fix : otdoa.Fix
        The fix as ``otdoa.Solver.solve`` returns it (``ok``, ``reason``, ``polish_rejected``).
    """
    return _wls_fix(*check_links(bs_xyz, toa_s, sigma_m, ue_z), ue_z, solver)


def _wls_fix(b, t, s, ue_z, solver):
    """``wls_fix`` on links ``check_links`` has checked (the receiver checks them once per fix)."""
    order, w = difference_weights(s)
    f = (otdoa.Solver(len(b)) if solver is None else solver).solve(b[order], t[order], ue_z, weights=w)
    if not np.all(np.isfinite(f.xyz)):
        return np.full(3, np.nan), np.nan, f
    p = f.xyz
    e = C * t - np.linalg.norm(p - b, axis=1)
    e_hat, _ = _gls_residuals(b, t, s, ue_z, p[:2])
    return np.array([p[0], p[1], np.sum(e / s**2) / np.sum(1 / s**2)]), float(np.sum((e_hat / s) ** 2)), f


def gls_residuals(bs_xyz, toa_s, sigma_m, ue_z: float, xy) -> tuple[np.ndarray, np.ndarray]:
    """The residual test's residuals at a fix: the ToAs' weighted least squares over (x, y, c δt), linearised at xy.

    ê = e − J (Jᵀ Σ⁻¹ J)⁺ Jᵀ Σ⁻¹ e, e_m = c τ_m − ‖p − b_m‖ at p = (xy, ue_z), J the Jacobian of e in (x, y, c δt),
    Σ = diag σ²: the residuals of one Gauss–Newton step of that least squares from xy, which its minimum leaves
    unchanged; independent of the clock, and to first order of where near the minimum xy lies.

    Parameters
    ----------
    bs_xyz, toa_s, sigma_m, ue_z
        As for ``wls_fix``.
    xy : float (2,)
        The fix, metres.

    Returns
    -------
    e_hat : float (M,)
        ê, metres.
    q_diag : float (M,)
        The diagonal of their covariance Q_e = Σ − J (Jᵀ Σ⁻¹ J)⁺ Jᵀ, m² (⁺: links left in a line leave it singular).
    """
    b, t, s = check_links(bs_xyz, toa_s, sigma_m, ue_z)
    if not np.all(np.isfinite(np.asarray(xy, dtype=np.float64)[:2])):
        raise ValueError(f"xy must be a finite fix (x, y), metres, got {xy!r}")
    return _gls_residuals(b, t, s, ue_z, xy)


def _gls_residuals(b, t, s, ue_z, xy):
    """``gls_residuals`` on checked links."""
    p = np.array([xy[0], xy[1], ue_z])
    u = (p - b)[:, :2] / np.maximum(np.linalg.norm(p - b, axis=1), 1e-9)[:, None]
    J = -np.column_stack([u, np.ones(len(b))])
    g = np.linalg.pinv((J / s[:, None]).T @ (J / s[:, None]))
    e = C * t - np.linalg.norm(p - b, axis=1)
    return e - J @ (g @ (J.T @ (e / s**2))), s**2 - np.einsum("mi,ij,mj->m", J, g, J)


def normalised_residuals(bs_xyz, toa_s, sigma_m, ue_z: float, q) -> np.ndarray:
    """Baarda's w-test statistics w_m = ê_m / √(Q_e)_mm at the fix q (module docstring, step 3).

    Parameters
    ----------
    bs_xyz, toa_s, sigma_m, ue_z
        As for ``wls_fix``.
    q : float (2,) or (3,)
        The fix, metres (``wls_fix``): its (x, y) is read.

    Returns
    -------
    float (M,)
        Standard normal for each link when every ToA is unbiased with its σ.
    """
    return _normalised(*check_links(bs_xyz, toa_s, sigma_m, ue_z), ue_z, q)


def _normalised(b, t, s, ue_z, q):
    """``normalised_residuals`` on checked links."""
    e_hat, q_diag = _gls_residuals(b, t, s, ue_z, q[:2])
    return e_hat / np.sqrt(np.maximum(q_diag, 1e-300))


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
        Every fit was found (False with ``reason`` where the SOCP failed: the fix is then NaN).
    reason : str
        Why not ok.
    fallback : bool
        The final fit's polish moved farther than ``otdoa.MAX_POLISH_MOVE_M`` and it kept its convex solution
        (``otdoa.Fix.polish_rejected``).
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
    fallback: bool


def threshold(dof: int, false_alarm: float = FALSE_ALARM) -> float:
    """The residual test's threshold: the 1 − ``false_alarm`` quantile of χ² with ``dof`` degrees of freedom.

    Parameters
    ----------
    dof : int
        Degrees of freedom, ≥ 1 (NaN for 0: nothing to test).
    false_alarm : float
        1e-6 to 0.5.

    Returns
    -------
    float
    """
    from scipy.stats import chi2  # (scipy.stats: 0.8 s to import, only for the NLoS test)

    _checks.in_range("false_alarm", false_alarm, 1e-6, 0.5)
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
        if not isinstance(exclude, (bool, np.bool_)):
            raise ValueError(f"exclude must be True or False, got {exclude!r}")
        self.exclude = bool(exclude)
        self._solvers = {}

    def solver(self, m: int) -> otdoa.Solver:
        """The compiled ``otdoa.Solver`` for m links (``wls_fix``'s), built on first use and kept.

        Parameters
        ----------
        m : int
            The number of links.

        Returns
        -------
        otdoa.Solver
        """
        if m not in self._solvers:
            self._solvers[m] = otdoa.Solver(m)
        return self._solvers[m]

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
        b, t, s = check_links(bs_xyz, toa_s, sigma_m, ue_z)
        active, excluded = list(range(len(b))), []
        q, stat, f = _wls_fix(b, t, s, ue_z, self.solver(len(b)))  # (links checked above: once per fix)
        detected = len(b) > 3 and stat > threshold(len(b) - 3, self.false_alarm)  # False where the SOCP failed (NaN)
        while self.exclude and len(active) - 3 >= 2 and stat > threshold(len(active) - 3, self.false_alarm):
            k = active[int(np.argmax(np.abs(_normalised(b[active], t[active], s[active], ue_z, q))))]
            active.remove(k)
            excluded.append(k)
            q, stat, f = _wls_fix(b[active], t[active], s[active], ue_z, self.solver(len(active)))
        dof = len(active) - 3
        thr = threshold(dof, self.false_alarm)
        ok = bool(np.all(np.isfinite(q)))
        return NlosFix(np.array([q[0], q[1], ue_z if ok else np.nan]), float(q[2]), stat, dof, thr, bool(detected),
                       tuple(excluded), bool(dof >= 1 and stat <= thr), ok, "" if ok else f.reason,
                       bool(f.polish_rejected))


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
        "otdoa_nlos_error_m" (T, S, J), metres; "otdoa_nlos_detected" (T, S, J); "otdoa_nlos_excluded" (T, S, J, I);
        "otdoa_nlos_fallback" (T, S, J), ``NlosFix.fallback``.
    """
    n_t, n_s, n_i = toa_s.shape
    n_j = len(m_values)
    xyz = np.full((n_t, n_s, n_j, 3), np.nan)
    detected, fallback = np.zeros((n_t, n_s, n_j), dtype=bool), np.zeros((n_t, n_s, n_j), dtype=bool)
    excluded = np.zeros((n_t, n_s, n_j, n_i), dtype=bool)
    for t in range(n_t):
        for j, m in enumerate(m_values):
            bs = bs_xyz[bs_index[t, :m]]
            for s in range(n_s):
                f = solver.fix(bs, toa_s[t, s, :m], sigma_m[t, s, :m], float(ue_xyz[t, 2]))
                xyz[t, s, j], detected[t, s, j], fallback[t, s, j] = f.xyz, f.detected, f.fallback
                excluded[t, s, j, list(f.excluded)] = True
    err = np.linalg.norm(xyz[..., :2] - ue_xyz[:, None, None, :2], axis=-1)
    return {"otdoa_sigma_m": np.asarray(sigma_m), "otdoa_nlos_xyz": xyz, "otdoa_nlos_error_m": err,
            "otdoa_nlos_detected": detected, "otdoa_nlos_excluded": excluded, "otdoa_nlos_fallback": fallback}
