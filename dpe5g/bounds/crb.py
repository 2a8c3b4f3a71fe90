"""Cramér–Rao bounds (CRB) of ToA and of the position: not in the paper, which cites the CRB of DPE but shows none.

Single link, frequency domain (the unitary DFT of eq. (5), the signal-model chapter): on the pilot subcarriers k ∈ K::

    Y_k = d_k Σ_l a_l e^{-j2π f_k (τ + δ_l)} + W_k,     W_k ~ CN(0, σ²),  |d_k| = 1,

with f_k the subcarrier's baseband frequency, τ the ToA, δ_l known tap delays (δ_0 = 0) and complex gains a_l
unknown.  The unknown gains are nuisance parameters: the Fisher information of τ is what is left of
J_ττ = (2/σ²) ‖∂μ/∂τ‖² after projecting ∂μ/∂τ off the span of the gains' columns (the Schur complement of the
Fisher matrix of (τ, Re a, Im a))::

    J_τ = (2/σ²) Re{ μ̇^H (I − A (A^H A)^{-1} A^H) μ̇ },   μ̇_k = −j2π f_k μ_k,   A_{k,l} = d_k e^{-j2π f_k (τ + δ_l)}

(``toa_fisher``; the pilots' phases cancel, so d_k = 1 below).  With one path (LoS, no other tap) this is the
classical ``J_τ = 8π² ρ Σ_k (f_k − f̄)² = 8π² ρ |K| β²``, ``ρ = |a_0|²/σ²`` the per-subcarrier SNR and β the
RMS bandwidth
about the mean frequency (the unknown phase of a_0 absorbs the mean, hence the centring); for N
contiguous subcarriers β = Δf √((N² − 1)/12) (``rms_bandwidth_hz``).

Position (the paper's search space, x, y and c δt at a known UE height): τ_m = (‖p − b_m‖ + c δt)/c, so the links'
ToA information adds up as J(θ) = Σ_m J_τ,m g_m g_mᵀ with g_m = ∂τ_m/∂θ = (u_m,x, u_m,y, 1)/c, u_m the unit vector
from BS m to the UE (``position_fisher``).  That is the DPE bound: every link's gains are its own nuisance
parameters and only τ_m depends on the position.  The two-step bound (``tdoa_position_crb``) starts instead from
the links' ToA estimates, efficient with variances 1/J_τ,m, forms differences to a reference link (the clock bias
cancels) and solves for (x, y) by weighted least squares with the differences' correlated covariance.  The two are
the same matrix (the clock bias is a nuisance parameter either way; the bounds chapter checks it numerically): with
independent per-link gains and known tap delays, DPE has no asymptotic advantage over two-step, and its gains lie
below the threshold SNR, where the CRB does not hold.

Units: frequencies Hz, delays and ToAs s, positions m, SNR dB (per subcarrier), Fisher information of a ToA in
1/s², of θ = (x, y, c δt) in 1/m².
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..common import _checks
from ..phy import nr, signal
from ..phy.nr import C, PAPER, Numerology
from ..simulation import chunk_cache, code_key, draw
from ..simulation.experiment import OTDOA_DETECTORS

#: the pilot subcarrier sets ``subcarrier_frequencies_hz`` knows: every FFT bin (the paper's full-band PRS), the
#: active subcarriers of the carrier (3276 for 273 RB), and a comb of them (the standard's PRS pattern)
SUBCARRIER_SETS = ("full", "active", "comb")


def subcarrier_frequencies_hz(subcarriers: str = "full", comb: int = 4, comb_offset: int = 0,
                              num: Numerology = PAPER) -> np.ndarray:
    """Baseband frequencies f_k of the pilot subcarriers.

    FFT bin k sits at k Δf for k < N/2 and at (k − N) Δf above (the negative frequencies).

    Parameters
    ----------
    subcarriers : str
        "full": all N FFT bins (the paper's PRS, ``nr.prs_symbols(pattern="full")``); "active": the n_active
        subcarriers of the carrier (``nr.active_bins``); "comb": every ``comb``-th active subcarrier from
        ``comb_offset`` (the bins of ``nr.prs_symbols(pattern="comb")``).
    comb : int
        The comb's spacing, 2, 4, 6 or 12 ("comb" only).
    comb_offset : int
        The comb's first active subcarrier, 0 to comb − 1 ("comb" only).
    num : Numerology
        The numerology (``nr.PAPER`` by default).

    Returns
    -------
    float (|K|,)
        f_k, Hz, one per pilot subcarrier k ∈ K.

    Raises
    ------
    ValueError
        When ``subcarriers``, ``comb`` or ``comb_offset`` is not one of its allowed values.
    """
    _checks.one_of("subcarriers", subcarriers, SUBCARRIER_SETS)
    if subcarriers == "full":
        bins = np.arange(num.n_fft)
    else:
        bins = nr.active_bins(num)
        if subcarriers == "comb":
            comb = _checks.integer("comb", comb, 2, 12)
            _checks.one_of("comb", str(comb), ["2", "4", "6", "12"])
            bins = bins[_checks.integer("comb_offset", comb_offset, 0, comb - 1)::comb]
    signed = np.where(bins < num.n_fft // 2, bins, bins - num.n_fft)
    return signed * num.scs_hz


def rms_bandwidth_hz(freqs_hz) -> float:
    """RMS bandwidth β = √(mean_k (f_k − f̄)²) of a subcarrier set about its mean frequency.

    Parameters
    ----------
    freqs_hz : float (|K|,)
        The pilot subcarriers' frequencies, Hz (``subcarrier_frequencies_hz``), at least two different.

    Returns
    -------
    float
        β, Hz.

    Raises
    ------
    ValueError
        When ``freqs_hz`` is not 1-D, finite, with two different frequencies.
    """
    f = _check_freqs(freqs_hz)
    return float(np.sqrt(np.mean((f - f.mean()) ** 2)))


def toa_fisher(freqs_hz, snr_db, gains=None, tap_delays_s=None) -> float:
    """Fisher information J_τ of the ToA of one link from known unit-modulus pilots, the gains of its taps unknown.

    The projection formula of the module docstring.

    Parameters
    ----------
    freqs_hz : float (|K|,)
        The pilot subcarriers' frequencies, Hz (``subcarrier_frequencies_hz``), at least two different.
    snr_db : float
        The per-subcarrier SNR of a unit-power channel, 10 log10(1/σ²), dB (the per-sample SNR of the signal-model
        chapter for the full band).
    gains : complex (L,) or None
        The tap gains; None: one path of unit power (the LoS case).
    tap_delays_s : float (L,) or None
        Their delays relative to the first path, seconds, ``|δ| ≤ 1e-4``; None: 0.

    Returns
    -------
    float
        J_τ, 1/s².

    Raises
    ------
    ValueError
        When the frequencies, the SNR or the taps are invalid (the taps: finite, not all zero).
    """
    f = _check_freqs(freqs_hz)
    noise_var = 10.0 ** (-float(signal.check_snr_db(snr_db)) / 10.0)
    a, delays = _check_taps(gains, tap_delays_s)
    # A, (|K|, L'): the gains' columns at τ = 0, one per distinct delay (taps at one delay share a column: TDL-D's
    # specular and Rayleigh parts, zero-gain padding), and the gains summed per column
    distinct, col = np.unique(delays, return_inverse=True)
    a_col = np.zeros(distinct.size, dtype=complex)
    np.add.at(a_col, col, a)
    basis, span = _columns_and_span(f.tobytes(), distinct.tobytes())  # the same for every link of one TDL profile
    return _projected_fisher(-2j * np.pi * f * (basis @ a_col), span, noise_var)


def toa_crb_s(freqs_hz, snr_db, gains=None, tap_delays_s=None) -> float:
    """√CRB of the ToA, 1/√J_τ (``toa_fisher``); with one path ``1/(2π β √(2 ρ |K|))``.

    Parameters
    ----------
    freqs_hz, snr_db, gains, tap_delays_s
        As for ``toa_fisher``.

    Returns
    -------
    float
        The bound, seconds.
    """
    return float(1.0 / np.sqrt(toa_fisher(freqs_hz, snr_db, gains, tap_delays_s)))


def window_model_toa_fisher(freqs_hz, snr_db, n_taps: int, gains=None, num: Numerology = PAPER) -> float:
    """Fisher information J_τ of the ToA under the channel model of eq. (8): L free complex taps on the sample grid.

    The taps sit at δ_l = l T_s and the true channel is such a channel.  J_τ is the true signal's derivative projected
    off the span of the L delayed copies: what is left of the information about τ once every tap of the window is free
    (the bounds chapter: about half of the one-path information for any L ≥ 12, not zero).

    Parameters
    ----------
    freqs_hz : float (|K|,)
        The pilot subcarriers' frequencies, Hz (``subcarrier_frequencies_hz``), at least two different.
    snr_db : float
        The per-subcarrier SNR of a unit-power channel, 10 log10(1/σ²), dB (the per-sample SNR of the signal-model
        chapter for the full band).
    n_taps : int
        L, 1 to N.
    gains : complex (≤ L,) or None
        The true channel's first taps, on δ_l = 0, T_s, …; None: one path of unit power.
    num : Numerology
        The numerology (T_s; ``nr.PAPER`` by default).

    Returns
    -------
    float
        J_τ, 1/s².

    Raises
    ------
    ValueError
        When an input is invalid (``gains``: 1 to L finite taps, not all zero).
    """
    f = _check_freqs(freqs_hz)
    noise_var = 10.0 ** (-float(signal.check_snr_db(snr_db)) / 10.0)
    n_taps = _checks.integer("n_taps", n_taps, 1, num.n_fft)
    a = np.ones(1, dtype=complex) if gains is None else np.atleast_1d(np.asarray(gains, dtype=complex))
    if a.ndim != 1 or not 1 <= a.size <= n_taps or not np.all(np.isfinite(a)) or not np.any(a != 0):
        raise ValueError(f"gains must be 1 to n_taps = {n_taps} finite complex taps, not all zero; got {a.shape}")
    window = np.exp(-2j * np.pi * np.outer(f, np.arange(n_taps) * num.sample_period_s))  # (|K|, L)
    mu = window[:, : a.size] @ a
    return _projected_fisher(-2j * np.pi * f * mu, _orthonormal_span(window), noise_var)


@functools.lru_cache(maxsize=8)
def _columns_and_span(f_key: bytes, delays_key: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The columns exp(−2πj f δ) of the distinct delays and their ``_orthonormal_span``, read-only (cached: every
    link of a TDL profile has the same delays)."""
    f, delays = np.frombuffer(f_key), np.frombuffer(delays_key)
    basis = np.exp(-2j * np.pi * np.outer(f, delays))
    span = _orthonormal_span(basis)
    basis.flags.writeable = span.flags.writeable = False
    return basis, span


def _orthonormal_span(basis) -> np.ndarray:
    """An orthonormal basis (|K|, r) of the span of ``basis``'s columns: its left singular vectors above lstsq's
    cutoff (ε max(|K|, L) times the largest singular value), so that projecting off it is lstsq's residual."""
    u, s, _ = np.linalg.svd(basis, full_matrices=False)
    return u[:, s > np.finfo(np.float64).eps * max(basis.shape) * s[0]]


def _projected_fisher(mu_dot, span, noise_var) -> float:
    """(2/σ²) Re{μ̇^H P⊥ μ̇}, P⊥ = I − Q Q^H the projector off the orthonormal columns Q of ``span``."""
    resid = mu_dot - span @ (span.conj().T @ mu_dot)
    return float(2.0 / noise_var * np.real(np.vdot(resid, resid)))


def position_fisher(ue_xyz, bs_xyz, toa_fisher_s) -> np.ndarray:
    """Fisher matrix of θ = (x, y, c δt) from the links' ToA information: Σ_m J_τ,m g_m g_mᵀ.

    With g_m = (u_m,x, u_m,y, 1)/c, u_m the unit vector from BS m to the UE.

    Parameters
    ----------
    ue_xyz : float (3,)
        The UE position, metres.
    bs_xyz : float (M, 3)
        Base-station positions, metres, M ≥ 3.
    toa_fisher_s : float (M,)
        Each link's J_τ, 1/s², > 0 (``toa_fisher``).

    Returns
    -------
    float (3, 3)
        The Fisher matrix, 1/m².

    Raises
    ------
    ValueError
        When the shapes do not match, M < 3, an input is not finite, a J_τ is not > 0 or the UE sits on a BS.
    """
    ue, bs, j = _check_geometry(ue_xyz, bs_xyz, toa_fisher_s)
    d = ue - bs
    g = np.column_stack([d[:, 0], d[:, 1], np.linalg.norm(d, axis=1)]) / np.linalg.norm(d, axis=1)[:, None] / C
    return (g * j[:, None]).T @ g


def position_crb(ue_xyz, bs_xyz, toa_fisher_s) -> np.ndarray:
    """CRB of θ = (x, y, c δt), the inverse of ``position_fisher``: the DPE bound.

    Parameters
    ----------
    ue_xyz, bs_xyz, toa_fisher_s
        As for ``position_fisher``.

    Returns
    -------
    float (3, 3)
        The CRB, m².

    Raises
    ------
    ValueError
        When the shapes do not match, M < 3, an input is not finite, a J_τ is not > 0 or the UE sits on a BS.
    """
    return np.linalg.inv(position_fisher(ue_xyz, bs_xyz, toa_fisher_s))


def horizontal_rmse_bound_m(crb) -> float:
    """The bound on the RMS horizontal error, √(CRB_xx + CRB_yy) (what Fig. 9 plots).

    Parameters
    ----------
    crb : float (3, 3) or (2, 2)
        A position CRB, m² (``position_crb``, ``tdoa_position_crb``).

    Returns
    -------
    float
        The bound, metres.
    """
    crb = np.asarray(crb, dtype=np.float64)
    return float(np.sqrt(crb[..., 0, 0] + crb[..., 1, 1]))


def tdoa_position_crb(ue_xyz, bs_xyz, toa_fisher_s, reference: int = 0) -> np.ndarray:
    """CRB of (x, y) of the two-step receiver.

    ToA estimates with variances 1/J_τ,m, their differences to link ``reference`` (the clock bias cancels), weighted
    least squares with the differences' covariance Σ = D diag(1/J_τ) Dᵀ: (Hᵀ Σ⁻¹ H)⁻¹, H the derivatives of the
    differences with respect to (x, y).

    Parameters
    ----------
    ue_xyz, bs_xyz, toa_fisher_s
        As for ``position_fisher``.
    reference : int
        The reference link, 0 to M − 1.

    Returns
    -------
    float (2, 2)
        The CRB, m².

    Raises
    ------
    ValueError
        As for ``position_fisher``, or when ``reference`` is out of range.
    """
    ue, bs, j = _check_geometry(ue_xyz, bs_xyz, toa_fisher_s)
    m = bs.shape[0]
    reference = _checks.integer("reference", reference, 0, m - 1)
    d = ue - bs
    u = d[:, :2] / np.linalg.norm(d, axis=1)[:, None] / C  # ∂τ_m/∂(x, y)
    others = [i for i in range(m) if i != reference]
    diff = np.zeros((m - 1, m))
    diff[np.arange(m - 1), others] = 1.0
    diff[:, reference] = -1.0
    cov = diff @ np.diag(1.0 / j) @ diff.T
    h = diff @ u
    return np.linalg.inv(h.T @ np.linalg.solve(cov, h))


def ml_toa_errors_s(res) -> np.ndarray:
    """The ToA errors of the ML estimator of one path in an experiment's results.

    The experiment is ``paper.ml_toa_experiment``, each link one path (los_mode "free_space": unit power, uniform phase,
    ToA set by the geometry), whose OTDoA peak detector (``otdoa.toa_from_spectrum`` "peak": the maximum of
    ``|ĥ(τ)|²``, eq. (10) with L = 1 for one link, on a grid of T_s / ``trials.OTDOA_UPSAMPLE``, refined by a parabola)
    is the ML ToA.

    Parameters
    ----------
    res : results.Results
        The results of a "free_space" experiment with the OTDoA baseline.

    Returns
    -------
    float (T·S·I,)
        Estimated ToA − (‖p − b_i‖ / c + δt) of every trial, SNR index and link, seconds, to compare with
        ``toa_crb_s(subcarrier_frequencies_hz("full"), snr_db)``.

    Raises
    ------
    ValueError
        When ``res`` is not of a "free_space" experiment with ``otdoa=True``.
    """

    e = res.experiment
    if e.scenario.los_mode != "free_space" or res.otdoa_toa_s is None:
        raise ValueError(f"res must come from a los_mode 'free_space' experiment with otdoa=True, got los_mode "
                         f"{e.scenario.los_mode!r}, otdoa={e.receiver.otdoa}")
    bs = e.load_deployment().bs_xyz[res.bs_index]  # (T, I, 3)
    true = np.linalg.norm(res.ue_xyz[:, None, :] - bs, axis=-1) / C + res.clock_bias_s[:, None]  # (T, I)
    est = res.otdoa_toa_s[:, :, OTDOA_DETECTORS.index("peak"), :]  # (T, S, I)
    return (est - true[:, None, :]).reshape(-1)


def rmse_bound_m(e, n_trials: int, snrs_db=None) -> np.ndarray:
    """The DPE bound on the horizontal error of an urban experiment, as an RMSE over its trials.

    √(mean_t (CRB_xx + CRB_yy)) per (SNR, M).  Each trial's links are the engine's (``draw.draw_links``: positions,
    channels with their tap delays known, per-link SNR); the pilots are the full band (the paper's, the engine's).  The
    Fisher information of a link scales with its linear SNR, so it is computed once per link and scaled.

    Parameters
    ----------
    e : experiment.Experiment
        The experiment.
    n_trials : int
        Its trials 0 … n_trials−1 to average over, 1 to ``e.run.n_trials``.
    snrs_db : float (S,) or None
        SNRs, dB, in the experiment's ``snr_convention``, to use instead of ``e.links.snrs_db`` (snr_mode "fixed" only:
        every link at each; the trials' links do not depend on the SNR, so one call serves several experiments of the
        same trials); None: the experiment's.

    Returns
    -------
    float (S, J)
        The bound, metres, the same (S, J) as ``Results.rmse_m``.

    Raises
    ------
    ValueError
        When ``n_trials`` is out of range, or ``snrs_db`` is given for an experiment whose SNRs come from the path loss.
    """
    n_trials = _checks.integer("n_trials", n_trials, 1, e.run.n_trials)
    if snrs_db is not None and e.links.snr_mode != "fixed":
        raise ValueError("snrs_db replaces the SNRs of a 'fixed' experiment; this one takes them from the path loss")
    snrs = np.asarray(e.links.snrs_db if e.links.snr_mode == "fixed" else (0.0,), dtype=np.float64)
    out = snrs if snrs_db is None else signal.check_snr_db(np.atleast_1d(snrs_db))
    links = link_information(e, n_trials)
    var = np.zeros((n_trials, out.size, len(e.receiver.m_values)))
    for t in range(n_trials):
        for s in range(out.size):
            j = links["info_0db"][t] * 10 ** ((links["link_snr_db"][t] + out[s] - snrs[0]) / 10)
            for jm, m in enumerate(e.receiver.m_values):
                var[t, s, jm] = np.trace(position_crb(links["ue"][t], links["bs"][t, :m], j[:m])[:2, :2])
    return np.sqrt(np.mean(var, axis=0))


def link_information(e, n_trials: int) -> dict:
    """The links of an urban experiment's trials as ``rmse_bound_m`` reads them.

    Computing the information costs a projection per link, so the arrays are kept beside the experiment's Monte Carlo
    results (``chunk_cache.cache_dir``, whose key covers the engine's code and the experiment) in a file keyed by this
    module's code; a later call with at most as many trials reads them.

    Parameters
    ----------
    e : experiment.Experiment
        The experiment.
    n_trials : int
        Its trials 0 … n_trials−1, 1 to ``e.run.n_trials``.

    Returns
    -------
    dict
        ue (T, 3) and bs (T, I, 3), metres; info_0db (T, I), each link's ToA Fisher information, 1/s², at 0 dB per
        subcarrier on the full band with its channel's tap delays known; link_snr_db (T, I), its SNR at the
        experiment's first SNR index, dB.
    """

    n_trials = _checks.integer("n_trials", n_trials, 1, e.run.n_trials)
    path = chunk_cache.cache_dir(e) / f"link-information-{code_key.code_digest(Path(__file__)).hex()[:16]}.npz"
    origin = {"link_information_of": e.config_key()}
    held = chunk_cache.read_cached(path, origin)  # (a damaged file is named, set aside and computed again)
    if held is not None and held["info_0db"].shape[0] >= n_trials:
        return {k: v[:n_trials] for k, v in held.items()}
    f = subcarrier_frequencies_hz("full")
    lk = draw.draw_links(e, n_trials)  # the engine's draws of every trial in one program
    info = [[toa_fisher(f, 0.0, g, d) for g, d in zip(gt, dt)] for gt, dt in zip(lk["gains"], lk["delays_s"])]
    out = {"ue": lk["ue_xyz"], "bs": lk["bs_xyz"], "info_0db": info, "link_snr_db": lk["link_snr_db"][:, 0]}
    out = {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}
    chunk_cache.write_cached(path, out, origin)
    return out


def _check_freqs(freqs_hz) -> np.ndarray:
    f = np.asarray(freqs_hz, dtype=np.float64)
    if f.ndim != 1 or f.size < 2 or not np.all(np.isfinite(f)):
        raise ValueError(f"freqs_hz must be a finite 1-D array of at least 2 frequencies in Hz, got shape {f.shape}")
    if np.ptp(f) == 0:
        raise ValueError("freqs_hz must hold at least two different frequencies (one frequency carries no ToA)")
    return f


def _check_taps(gains, tap_delays_s):
    a = np.ones(1, dtype=complex) if gains is None else np.atleast_1d(np.asarray(gains, dtype=complex))
    delays = np.zeros(a.shape) if tap_delays_s is None else np.atleast_1d(np.asarray(tap_delays_s, dtype=np.float64))
    if a.ndim != 1 or delays.shape != a.shape:
        raise ValueError(f"gains and tap_delays_s must be 1-D of equal length, got {a.shape} and {delays.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(delays))) or not np.any(a != 0):
        raise ValueError("gains must be finite and not all zero, tap_delays_s finite (seconds)")
    if np.any(np.abs(delays) > 1e-4):
        raise ValueError(f"tap_delays_s must be in seconds, |δ| ≤ 1e-4 s; got up to {np.max(np.abs(delays))!r}")
    return a, delays


def _check_geometry(ue_xyz, bs_xyz, toa_fisher_s):
    ue = np.asarray(ue_xyz, dtype=np.float64)
    bs = np.asarray(bs_xyz, dtype=np.float64)
    j = np.atleast_1d(np.asarray(toa_fisher_s, dtype=np.float64))
    if ue.shape != (3,) or bs.ndim != 2 or bs.shape[1] != 3 or j.shape != (bs.shape[0],):
        raise ValueError(f"ue_xyz must be (3,), bs_xyz (M, 3) and toa_fisher_s (M,); got {ue.shape}, {bs.shape}, "
                         f"{j.shape}")
    if bs.shape[0] < 3:
        raise ValueError(f"at least 3 base stations are needed for (x, y, c δt), got M = {bs.shape[0]}")
    if not (np.all(np.isfinite(ue)) and np.all(np.isfinite(bs)) and np.all(np.isfinite(j)) and np.all(j > 0)):
        raise ValueError("ue_xyz and bs_xyz must be finite and toa_fisher_s finite and > 0 (1/s²)")
    if np.any(np.linalg.norm(ue - bs, axis=1) == 0):
        raise ValueError("ue_xyz must not coincide with a base station")
    return ue, bs, j
