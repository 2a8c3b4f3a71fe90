"""The DPE receiver: correlograms from the received spectra, then a fix in a window whose centre is in metres.

The fix is by one of two searches (``grid_search``: the paper's divide-and-conquer grid; ``certified_search``: branch
and bound).  The module also holds the engine's noise-mixing identity, in this one place.  The engine draws one unit
noise spectrum η per trial and scales it to each SNR (``spectrum_at``); without PRS reuse the received spectrum at SNR
index s is a_s·y0 + b_s·η for real scales (``noise_scales``).  Both receivers' correlograms are linear in the CIR
estimate's energy, ``|a ĥ0 + b ĥη|² = a² |ĥ0|² + 2ab Re(ĥ0* ĥη) + b² |ĥη|²``, so a trial computes three parts once
(``energy_parts``, and their images ``energy_window_parts``, ``spline_noise_basis``) and every SNR's correlogram is
their mixture (``mix_parts``) — two transforms per BS and trial instead of one per SNR.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import signal
from ..phy.nr import C, PAPER, Numerology
from . import certified_search, correlogram, cost, grid_search
from .search_config import SearchConfig, WindowFix


def receiver_correlogram(g, cfg: SearchConfig, window=None):
    """The per-BS correlograms the chosen search reads, from the LS spectrum (traceable).

    ``correlogram.energy_grid`` on T_s/upsample (in ``correlogram.GRID_DTYPE``) for "grid",
    ``correlogram.spline_coefficients`` (float64) for "bnb".  Rows are per BS, so the M nearest of them serve any M.

    Parameters
    ----------
    g : complex (M, N)
        The LS spectrum (``correlogram.ls_spectrum``).
    cfg : SearchConfig
        The search; its ``method``, "grid" or "bnb", picks the correlogram.
    window : complex (N + 1,) or None
        For "bnb", ``correlogram.window_spectrum(cfg.n_taps, N)`` passed as an array (then ``cfg.n_taps`` and
        ``cfg.window_decay_s`` are not read, and a compiled caller serves every window); None computes it from them.

    Returns
    -------
    array (M, N·U)
        The energy grid (complex64 energies on T_s/``cfg.upsample``) or the spline coefficients (float64, U =
        ``cfg.spline_upsample``).
    """
    if cfg.method == "bnb":
        if window is None:
            window = jnp.asarray(correlogram.window_spectrum(cfg.n_taps, g.shape[-1], cfg.tap_weights()))
        return correlogram.spline_coefficients(g, window, cfg.spline_upsample)
    return correlogram.energy_grid(g.astype(correlogram.GRID_DTYPE), cfg.n_taps, cfg.upsample)


def fix_in_window(g, bs_xyz, center_m, cfg: SearchConfig, num: Numerology = PAPER, corr=None) -> WindowFix:
    """One DPE fix with either search (traceable).

    Parameters
    ----------
    g : complex (M, N) or None
        The LS spectrum (``correlogram.ls_spectrum``); None only where ``corr`` is given and the search does not
        read it.
    bs_xyz : float (M, 3)
        Base-station positions, metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The search and its window.
    num : Numerology
        The numerology.
    corr : array or tuple or None
        ``receiver_correlogram`` of g (or of more BSs, of which the first M rows are read), a window of it
        (``grid_search.grid_window``, ``spline_bounds.spline_window``), or None to compute it.

    Returns
    -------
    WindowFix
        The fix in the window.
    """
    _checks.require_x64()
    corr = receiver_correlogram(g, cfg) if corr is None else corr
    if cfg.method == "bnb":
        return certified_search.certified_search(corr, bs_xyz, center_m, cfg, num)[0]
    q = grid_search.search(corr, g, bs_xyz, center_m, cfg, num, with_cost=False)
    return grid_search.grid_fix(q, center_m, cfg)


def receiver_window(cfg: SearchConfig, prs_reuse: int, num: Numerology = PAPER) -> np.ndarray:
    """The certified search's window (``correlogram.window_spectrum``) of the receiver ``cfg``.

    L taps T_s apart for the paper's full-band pilots; with PRS reuse the pilots fill only the carrier's contiguous band
    of active subcarriers, and the taps are spaced ``correlogram.band_tap_spacing`` samples apart (their tap weights
    too), so that the window's energy stays the ML cost of L free taps (eq. (8) with the band's own orthogonal taps).

    Parameters
    ----------
    cfg : SearchConfig
        The receiver's search (L = ``n_taps`` and its tap weights).
    prs_reuse : int
        The PRS reuse factor; 0: none (full-band pilots).
    num : Numerology
        The numerology.

    Returns
    -------
    numpy.ndarray, complex (N + 1,)
        The window's multiplier on the energy's harmonics.
    """
    if not prs_reuse:
        return correlogram.window_spectrum(cfg.n_taps, num.n_fft, cfg.tap_weights(num))
    s = correlogram.band_tap_spacing(num)
    weights = correlogram.tap_weights(cfg.n_taps, cfg.window_decay_s, num.sample_period_s * s)
    return correlogram.window_spectrum(cfg.n_taps, num.n_fft, weights, tap_spacing=s)


def spectrum_at(d, s):
    """Received spectrum of SNR index s: the trial's noise-free spectrum plus σ_s times its unit noise.

    The noise is drawn in the frequency domain, CN(0, 1) per bin, once per trial (``draw.draw_fn``), and scaled to
    each SNR's variance (``signal.noise_variance``): the DFT is unitary, so this is exactly time-domain AWGN of
    that variance.  One draw serves every SNR (common random numbers): each SNR's noise has the right distribution,
    and the SNRs of one trial differ only in the noise level, as its M values differ only in the links used.

    Scale.  With snr_mode "fixed" every link has unit signal power and noise σ_s² (one SNR for all links, so the
    common scale does not matter to the receivers).  Where the links' powers differ (snr_mode "link_budget" and
    "nearest") the spectra are what one receiver sees: one noise floor, CN(0, 1) per bin, and each BS's signal
    s_b/σ_b at its own received power (s_b of unit power, σ_b its noise level).  A receiver that scaled each link to
    unit signal power would need each link's true SNR, and the DPE cost of eq. (10), which sums the BSs' energies,
    would then weigh a weak link's noise as much as a strong link's signal.

    With PRS reuse (``d.reuse``) the UE receives one signal per resource r, Y_r = Σ_{b on r} s_b/σ_b + η_r, and
    each link reads the Y_r of its resource: co-channel links read the same REs, so the same signal and the same
    noise (η_r is the unit noise of the nearest link on r).  Without ``co_channel`` the other BSs' signals are left
    out.

    Parameters
    ----------
    d : simulation.trial_draw.TrialDraw
        The trial's draws.
    s : int
        The SNR index (may be traced).

    Returns
    -------
    complex (I, N)
        The received spectrum of the trial's I links.
    """
    sigma = jnp.sqrt(signal.noise_variance(d.link_snr_db[s], d.prs))
    if not d.per_link_power:  # snr_mode "fixed": every link at the same SNR, unit signal power
        return d.y0 + sigma[:, None] * d.noise
    own = d.y0 / sigma[:, None]  # in units of the noise: the link's own signal at its received power
    if d.reuse is None:
        return own + d.noise
    res = d.reuse.res
    eta = d.noise[jnp.argmax(res[None, :] == res[:, None], axis=1)]  # the nearest co-channel link's noise
    x = d.reuse.co_channel
    if x is None:
        return own + eta
    sigma_x = jnp.sqrt(signal.noise_variance(x.snr_db[s], x.prs))
    rx = jax.ops.segment_sum(jnp.concatenate([own, x.y0 / sigma_x[:, None]]),
                             jnp.concatenate([res, x.res]), num_segments=d.reuse.n_res)
    return rx[res] + eta


def noise_scales(d):
    """The real scales (a, b) with ``spectrum_at(d, s)`` = a[s, :, None] · y0 + b[s, :, None] · noise.

    Every link reads its own noise-free spectrum and the trial's unit noise (no PRS reuse).

    Parameters
    ----------
    d : simulation.trial_draw.TrialDraw
        The trial's draws.

    Returns
    -------
    tuple of float (S, I), or None
        (a, b); None with PRS reuse, where a link reads a sum over the BSs of its resource.
    """
    if d.reuse is not None:
        return None
    sigma = jnp.sqrt(signal.noise_variance(d.link_snr_db, d.prs))  # (S, I), as ``spectrum_at``'s
    if not d.per_link_power:
        return jnp.ones_like(sigma), sigma
    return 1.0 / sigma, jnp.ones_like(sigma)


def energy_parts(h0, hn) -> jax.Array:
    """The three parts of the energy of a·ĥ0 + b·ĥn for real a, b, which ``mix_parts`` mixes.

    ``|a ĥ0 + b ĥn|² = a² |ĥ0|² + 2ab Re(ĥ0* ĥn) + b² |ĥn|²``.

    Parameters
    ----------
    h0, hn : complex (...)
        The CIR estimates of two spectra (the noise-free spectrum and the unit noise, ``noise_scales``).

    Returns
    -------
    float (3, ...)
        ``|ĥ0|²``, Re(ĥ0* ĥn) and ``|ĥn|²``.
    """
    return jnp.stack([h0.real**2 + h0.imag**2, h0.real * hn.real + h0.imag * hn.imag, hn.real**2 + hn.imag**2])


def mix_parts(parts, a, b) -> jax.Array:
    """a² P_0 + 2ab P_1 + b² P_2: the correlogram of the spectrum a·g0 + b·gn from the three parts of its correlogram.

    Parameters
    ----------
    parts : float (3, ..., M, J)
        The parts P_0, P_1, P_2 (``energy_parts`` after any linear map: the L-tap window sum, the spline's transform).
    a, b : float (..., M)
        The real scales of g0 and gn.

    Returns
    -------
    float (..., M, J)
        The mixed correlogram.
    """
    a, b = jnp.asarray(a)[..., None], jnp.asarray(b)[..., None]
    return (a * a) * parts[0] + (2.0 * a * b) * parts[1] + (b * b) * parts[2]


def energy_window_parts(h0w, hnw, n_taps: int, n_fft: int) -> jax.Array:
    """``correlogram.energy_window``'s three parts (``energy_parts``) for the windows of two spectra g0, gn.

    ``mix_parts`` of the result is the window of the correlogram of a·g0 + b·gn, for every a, b.

    Parameters
    ----------
    h0w, hnw : complex (..., M, U, W/U + L − 1)
        The windows (``correlogram.cir_window``) of the CIR estimates of g0 and gn.
    n_taps : int
        The window L, taps.
    n_fft : int
        N.

    Returns
    -------
    float (3, ..., M, W)
        The three parts of the correlogram's window.
    """
    return correlogram.window_sums(energy_parts(h0w, hnw) * n_fft, n_taps)


def spline_noise_basis(g0, gn, window, upsample: int) -> jax.Array:
    """The spline coefficients of the three parts of the energy (``energy_parts``) of the LS spectrum a·g0 + b·gn.

    For any real scales a, b per BS: ``correlogram.spline_from_energy`` is linear, so the coefficients of
    a·g0 + b·gn are ``mix_parts`` of these.  One basis per trial serves all its SNRs, 2 inverse FFTs and 3 spline maps
    per BS instead of 1 and 1 per SNR.

    Parameters
    ----------
    g0, gn : complex (..., M, N)
        The LS spectra of the noise-free spectrum and of the unit noise.
    window : complex (N + 1,)
        ``correlogram.window_spectrum``.
    upsample : int
        U, knots per sample (even).

    Returns
    -------
    float (3, ..., M, N·U)
        The basis, float64 as ``correlogram.spline_coefficients`` (round-off of the mixture, relative to the largest
        part, ~1e-16).
    """
    # the two transforms in a loop, so that its input is computed once (XLA on the CPU would otherwise fuse the
    # producers of g0 and gn, such as the noise draw, into the transform's zero padding)
    h0, hn = jax.lax.map(correlogram.half_sample_cir, jnp.stack([g0, gn]))
    return correlogram.spline_from_energy(energy_parts(h0, hn) * g0.shape[-1], window, upsample)


def spline_correlograms(d, cfg: SearchConfig, window):
    """s → the certified search's spline coefficients at SNR index s, traceable.

    They are ``receiver_correlogram`` of ``spectrum_at(d, s)``'s LS spectrum with ``window``.  Without PRS reuse
    they are mixed from a basis of the trial computed once (``noise_scales``, ``spline_noise_basis``), equal to the
    per-SNR path up to round-off (~1e-16 relative; a test checks it).

    Parameters
    ----------
    d : simulation.trial_draw.TrialDraw
        The trial's draws.
    cfg : SearchConfig
        The certified search.
    window : complex (N + 1,)
        ``correlogram.window_spectrum``.

    Returns
    -------
    callable
        s → float (I, N·U).
    """
    form = noise_scales(d)
    if form is None:
        return lambda s: receiver_correlogram(correlogram.ls_spectrum(spectrum_at(d, s), d.prs), cfg, window)
    a, b = form
    basis = spline_noise_basis(correlogram.ls_spectrum(d.y0, d.prs), correlogram.ls_spectrum(d.noise, d.prs),
                               window, cfg.spline_upsample)
    return lambda s: mix_parts(basis, a[s], b[s])


def grid_windows(d, cfg: SearchConfig):
    """The grid search's correlograms of the trial d, read only in windows (``grid_search.grid_window``).

    A window is W of the N·U grid points.  The CIR estimates on T_s/U (``correlogram.cir_grid``, in
    ``correlogram.GRID_DTYPE``) are computed whole, the energies only in the window.  Without PRS reuse
    (``noise_scales``) the CIR estimates of y0 and η are computed once per trial (2 inverse FFTs of length U·N per BS
    instead of one per SNR), and windows mixes the parts (``mix_parts``): equal to the per-SNR path up to complex64
    round-off (~2e-7 relative; a test checks it).

    Parameters
    ----------
    d : simulation.trial_draw.TrialDraw
        The trial's draws.
    cfg : SearchConfig
        The grid search.

    Returns
    -------
    parts : callable or None
        start → the three parts (3, I, W) of the windows (``energy_window_parts``), which ``mixed_grid_fixes`` reads for
        all SNRs at once; None with PRS reuse.
    windows : callable
        (s, start) → the pair (values (I, W), start) that ``grid_search.search`` reads at SNR index s for windows
        starting at grid points start (I,), traceable.
    """
    dt, u, taps, n = correlogram.GRID_DTYPE, cfg.upsample, cfg.n_taps, d.prs.shape[-1]
    width = grid_search.grid_window_cells(cfg, PAPER)
    form = noise_scales(d)

    def cir(y):
        return correlogram.cir_grid(correlogram.ls_spectrum(y, d.prs).astype(dt), u)

    if form is None:
        def windows(s, start):
            return correlogram.energy_window(correlogram.cir_window(cir(spectrum_at(d, s)), start, width, taps, u),
                                             taps, n), start
        return None, windows
    a, b = form
    # the two transforms in a loop: its input, the two spectra, is then computed once (XLA on the CPU would
    # otherwise fuse the noise draw and the signal's phasors into the zero padding of the transform, measured 2×)
    h0, hn = jax.lax.map(cir, jnp.stack([d.y0, d.noise]))

    def parts(start):
        return energy_window_parts(correlogram.cir_window(h0, start, width, taps, u),
                                   correlogram.cir_window(hn, start, width, taps, u), taps, n)

    def windows(s, start):
        return mix_parts(parts(start), a[s], b[s]), start
    return parts, windows


def parts_terms(parts, start, pos):
    """The per-BS terms of ``cost.lookup`` for the three parts of a correlogram window, at positions pos.

    One gather of the 3 × 4 values and one set of cubic weights per lookup, for all parts.

    Parameters
    ----------
    parts : float (3, M, W)
        The window's parts (``energy_window_parts``).
    start : int (M,)
        The grid point where each BS's window starts.
    pos : float (..., M)
        Positions, grid units.

    Returns
    -------
    float (3, ..., M)
        The terms of each part.
    """
    f = jnp.floor(pos)
    first = f.astype(jnp.int64) - start - 1
    rows = jnp.broadcast_to(jnp.arange(parts.shape[1]), first.shape)
    dims = jax.lax.GatherDimensionNumbers(offset_dims=(first.ndim, first.ndim + 1), collapsed_slice_dims=(1,),
                                          start_index_map=(1, 2))
    v = jax.lax.gather(parts, jnp.stack([rows, first], axis=-1), dims, slice_sizes=(3, 1, 4),
                       mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS)  # (..., M, 3, 4)
    terms = jnp.einsum("...q,...pq->...p", cost.catmull_rom_weights(pos - f), v)  # (..., M, 3)
    return jnp.moveaxis(terms, -1, 0)


def mixed_grid_fixes(parts, start, a, b, bs_xyz, center_m, cfg: SearchConfig, m_values,
                     num: Numerology = PAPER) -> WindowFix:
    """``grid_search.nested_grid_fixes`` for S received spectra a_s·g0 + b_s·gn at once.

    The S spectra are the engine's SNRs of one trial, read from the three parts of their correlograms' windows around
    one centre: the correlogram of spectrum s is ``mix_parts(parts, a_s, b_s)``, and so is its cubic lookup, which is
    linear in the grid values.  The first level — 94 % of Fig. 9's candidates — is looked up once for the three parts
    instead of once per spectrum, and the cost of every (s, M) is one matrix product over the BSs; the finer levels run
    per (s, M) on the mixed window.  Equal to ``nested_grid_fixes`` up to round-off (the weights form of the cubic and
    the order of the sums; a test checks the fixes agree).

    Parameters
    ----------
    parts : float (3, I, W)
        ``energy_window_parts`` of the I ≥ max(m_values) nearest BSs.
    start : int (I,)
        The grid points where the windows start (``grid_search.grid_window`` of center_m).
    a, b : float (S, I)
        The scales of each spectrum.
    bs_xyz : float (I, 3)
        Base-station positions, metres.
    center_m : float (4,)
        The window's centre [x, y, z, c δt], metres.
    cfg : SearchConfig
        The grid search, with ``polish`` False (the polish reads each spectrum).
    m_values : sequence of int
        The numbers M of nearest BSs to fix with.
    num : Numerology
        The numerology.

    Returns
    -------
    WindowFix
        With leading axes (S, len(m_values)).

    Raises
    ------
    ValueError
        When ``cfg`` is not the grid search or has ``polish`` set.
    """
    _checks.require_x64()
    if cfg.method != "grid" or cfg.polish:
        raise ValueError(f"mixed_grid_fixes runs the grid search without polish; got method {cfg.method!r}, "
                         f"polish {cfg.polish!r}")
    ts = num.sample_period_s
    cand, n_b = grid_search.level_candidates(center_m, cfg, 0)
    m_max = max(m_values)
    grid = cand.reshape(-1, n_b, 4)
    dist = jnp.linalg.norm(grid[:, 0, None, :3] - bs_xyz[:m_max], axis=-1) / C  # as ``candidate_terms``
    # cost of (s, M) at each candidate: Σ_{m < M} (a² T_0 + 2ab T_1 + b² T_2), one product over (part, BS)
    mix = jnp.stack([a * a, 2.0 * a * b, b * b], axis=1)[..., :m_max]  # (S, 3, m_max)
    upto = (np.arange(m_max)[:, None] < np.asarray(m_values)[None, :]).astype(float)  # (m_max, J)
    weights = jnp.einsum("spm,mj->pmsj", mix, upto).reshape(3 * m_max, -1)  # (3 m_max, S J)

    def per_bias(bias_s):  # one c δt offset: the ToAs of every (x, y) point shift by it
        terms = parts_terms(parts[:, :m_max], start[:m_max], (dist + bias_s) / ts * cfg.upsample)  # (3, XY, M)
        return jnp.moveaxis(terms, 0, 1).reshape(dist.shape[0], -1) @ weights  # (XY, S J)

    # a loop over the offsets, so that the distances (and the window's start) are computed once, not again inside
    # each lookup (XLA on the CPU fuses such small producers into the large loops that read them)
    costs = jax.lax.map(per_bias, grid[0, :, 3] / C)  # (n_b, XY, S J)
    costs = jnp.swapaxes(costs, 0, 1).reshape(cand.shape[0], -1)  # (K, S J), candidates in ``cand``'s order
    first = cand[jnp.argmax(costs, axis=0)].reshape(a.shape[0], len(m_values), 4)  # (S, J, 4)

    def per_spectrum(x):
        a_s, b_s, first_s = x
        corr = (mix_parts(parts, a_s, b_s), start)
        qs = [grid_search.search(grid_search.first_rows(corr, m), None, bs_xyz[:m], center_m, cfg, num,
                                 with_cost=False, first_level=first_s[j]) for j, m in enumerate(m_values)]
        return jnp.stack(qs)

    return grid_search.grid_fix(jax.lax.map(per_spectrum, (a, b, first)), center_m, cfg)  # (S, J, ...)
