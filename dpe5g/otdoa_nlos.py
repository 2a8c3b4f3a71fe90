"""The NLoS-aware OTDoA receiver (ours, beyond the paper): per-link ToA variances, a weighted fix, and NLoS links
detected and excluded by a residual test (RAIM-style fault detection and exclusion).

The paper's OTDoA baseline (``otdoa``) fits every detected first path with equal weight.  This receiver:

1. ``link_sigma_m`` — each link's first-path ToA (``otdoa.toa``'s detector) and its standard deviation in metres,
   from the link's own correlogram only (eq. (O1) of the NLoS chapter):

       σ_m² = σ_CRB,m² + c² (τ̂_peak,m − τ̂_first,m)² / 12,     σ_CRB,m = c √3 / (√2 π B √SNR̂_m),

   σ_CRB the Cramér–Rao bound of a ToA over a flat band B (the pilots' occupied bandwidth; RMS bandwidth B/√12)
   at the link's post-correlation SNR SNR̂ = (peak − floor) / floor of its correlogram, the noise floor its mean,
   read from its median (the noise's energy is exponential: mean = median / ln 2); the second term, a uniform spread over
   the span between the first path and the strongest peak, grows when multipath (NLoS: a weak or absent direct path)
   separates them.  No truth enters: neither the SNR the experiment set, nor the LoS state.
2. ``wls_fix`` — the weighted least squares of the ToAs over (x, y, c δt), the UE height known:
   minimise Σ_m (c τ_m − ‖p − b_m‖ − c δt)² / σ_m²  (the TDoA fit with its full covariance, the clock kept
   explicit so that any subset of links is fitted alike), by Gauss–Newton from the SOCP fix of ``otdoa.Solver``.
3. ``NlosSolver.fix`` — the test statistic T = Σ_m e_m² / σ_m² of the fit is χ² with M − 3 degrees of freedom when
   every ToA is unbiased with the modelled σ.  T above its 1 − ``FALSE_ALARM`` quantile detects an inconsistent set;
   with M − 3 ≥ 2 the link whose leave-one-out fit has the least T is excluded and the test repeated on the rest;
   an exclusion is made only while the remaining links can still be tested (M − 3 ≥ 1 after it).  With the 4
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

    Parameters
    ----------
    e : float (M, J)
        Each link's one-tap correlogram (the energy of ĥ(τ)) on a uniform grid of the period (``correlogram.energy_grid``).
    toa_first_s, toa_peak_s : float (M,)
        The first-path and strongest-peak ToAs, seconds (``otdoa.toa``, "first_path" and "peak").
    bandwidth_hz : float
        B, the pilots' occupied bandwidth, Hz.

    Returns
    -------
    float (M,)
        σ_m, metres.
    """
    e = np.asarray(e, dtype=np.float64)
    floor = np.median(e, axis=-1) / np.log(2.0)
    snr = np.maximum(np.max(e, axis=-1) - floor, 1e-300) / floor
    crb = C * np.sqrt(3.0) / (np.sqrt(2.0) * np.pi * bandwidth_hz * np.sqrt(snr))
    spread = C * np.abs(np.asarray(toa_peak_s) - np.asarray(toa_first_s))
    return np.sqrt(crb**2 + spread**2 / 12.0)


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
    e, first, peak = (np.asarray(a) for a in _grid_and_toas(g, upsample, float(threshold_db), max_lead_samples,
                                                             num.sample_period_s))
    occupied = np.count_nonzero(np.abs(np.asarray(prs)) > 0, axis=-1).mean()
    return first, sigma_from_grid(e, first, peak, occupied * num.scs_hz)


@partial(jax.jit, static_argnames=("upsample", "max_lead_samples"))
def _grid_and_toas(g, upsample, threshold_db, max_lead_samples, ts):
    """The one-tap energy grid of each link and its first-path and peak ToAs (``otdoa.toa_row``), in one program."""
    e = correlogram.energy_grid(g.astype(correlogram.GRID_DTYPE), 1, upsample)
    toas = [jax.vmap(lambda row, m=method: otdoa.toa_row(row, m, upsample, threshold_db, max_lead_samples, ts))(e)
            for method in ("first_path", "peak")]
    return (e, *toas)


def _residual(b, t, ue_z, q):
    """e_m = c τ_m − ‖p − b_m‖ − c δt at q = (x, y, c δt); metres."""
    p = np.array([q[0], q[1], ue_z])
    return C * t - np.linalg.norm(p - b, axis=1) - q[2]


def wls_fix(bs_xyz, toa_s, sigma_m, ue_z: float, xy0, iters: int = 30) -> tuple[np.ndarray, float]:
    """The weighted least-squares fix of step 2 of the module docstring, by Gauss–Newton with step halving.

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
        else:
            break
        q, cost = q + step, new
        if np.linalg.norm(step) < WLS_STOP_STEP_M:
            break
    return q, float(cost)


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
            trials = [(wls_fix(b[rest], t[rest], s[rest], ue_z, q[:2]), k)
                      for k in active for rest in [[i for i in active if i != k]]]
            (q, stat), k = min(trials, key=lambda tr: tr[0][1])
            active.remove(k)
            excluded.append(k)
        dof = len(active) - 3
        thr = threshold(dof, self.false_alarm)
        return NlosFix(np.array([q[0], q[1], ue_z]), float(q[2]), stat, dof, thr, bool(detected), tuple(excluded),
                       bool(dof >= 1 and stat <= thr), True, "")
