"""The per-trial programs of the engine: trial key → draws (``draw``) → receiver (``receiver``) → scored fixes; and
one trial as the receivers see it (``example``).

The grid search runs as one program per trial (``grid_trial_fn``).  The certified search runs as two, the draws and
the windows of the spline correlograms (``bnb_prep_fn``), then the search per (SNR, M) (``bnb_fix_fn``), so that
the search, the slow part to compile, is compiled once per search config, M values and number of SNRs for every
experiment.  The OTDoA baseline's step 1 (ToAs, ``toa_fn``) runs in XLA on the same signals, its convex fixes in
NumPy (``otdoa_fixes``).  Every function reads the parts of an ``Experiment`` that ``program_config`` keeps, so
experiments that differ elsewhere share one compiled program.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..common import _checks
from ..phy import deployment, signal
from ..phy.nr import C, PAPER
from ..receivers import correlogram, dpe_nlos, grid_search, otdoa, otdoa_nlos, receiver, toa_fit
from ..receivers.search_config import SearchConfig, WindowFix
from ..receivers.spline_boxes import spline_window
from .draw import draw_fn, prior_center
from .experiment import OTDOA_DETECTORS, Experiment, Receiver
from .trial_draw import CoChannelDraw, ReuseDraw, TrialDraw, trial_key

#: OTDoA ToA detector settings used by the engine (``dpe5g.receivers.otdoa.toa``'s defaults)
OTDOA_UPSAMPLE = 8
OTDOA_THRESHOLD_DB = -10.0
OTDOA_MAX_LEAD = 64

#: the programs of a run, each compiled for the part of the experiment it reads (``program_config``)
PROGRAMS = ("grid_trial", "bnb_prep", "bnb_fix", "toa", "prior")


def program_config(e: Experiment, program: str) -> Experiment | tuple[SearchConfig, tuple[int, ...]]:
    """The part of ``e`` that ``program`` reads; the one key of compiled programs.

    Every program: not the name, the seed (it enters through the trial keys), nor the trial and chunk counts. "toa":
    nothing else is cleared; the others: nor ``otdoa_nlos``; "prior" nothing more.  "grid_trial", "bnb_prep": nor how
    a non-truth window centre is obtained (it enters as an input), and for the certified search the receiver window L and its weights (they enter as
    ``correlogram.window_spectrum``, an input).  "bnb_fix": the receiver's ``SearchConfig`` without its window (it
    enters through the coefficients) and the M values, a pair.  Experiments that differ only in what is cleared share
    one compiled program (and, through JAX's persistent compilation cache, one compiled executable across processes).

    Parameters
    ----------
    e : Experiment
        The experiment.
    program : str
        One of ``PROGRAMS``.

    Returns
    -------
    Experiment or tuple of (SearchConfig, tuple of int)
        ``e`` with what ``program`` does not read cleared; for "bnb_fix", the pair (search, M values).

    Raises
    ------
    ValueError
        When ``program`` is not one of ``PROGRAMS``.
    """
    if program not in PROGRAMS:
        raise ValueError(f"program must be one of {PROGRAMS}, got {program!r}")
    run_free = e.replace(name="program", seed=0, n_trials=1, chunk_trials=1)  # (the run: not a program's)
    if program == "toa":
        return run_free.replace(dpe_nlos=False)  # read by "bnb_prep" only
    run_free = run_free.replace(otdoa_nlos=False)  # read by "toa" only
    if program == "prior":
        return run_free.replace(dpe_nlos=False)
    if program == "bnb_fix":
        return dataclasses.replace(e.receiver_search(), n_taps=1, window_decay_s=0.0), tuple(e.receiver.m_values)
    search = (dataclasses.replace(e.receiver.search, n_taps=1, window_decay_s=0.0) if e.receiver.search.method == "bnb"
              else e.receiver.search)
    d = Receiver()
    centre = {} if e.receiver.centring == "truth" else dict(centring="prior", prior_kind=d.prior_kind,
                                                    prior_scale_m=d.prior_scale_m, otdoa=False,
                                                    toa_method=d.toa_method)
    return run_free.replace(search=search, **centre)


def truth_center(d: TrialDraw) -> jax.Array:
    """The window centre of centring "truth" (the paper's set-up, a labelled comparison): the true position and c δt.

    Parameters
    ----------
    d : TrialDraw
        The trial's draws.

    Returns
    -------
    float (4,)
        [x, y, z, c δt], metres.
    """
    return jnp.concatenate([d.ue_xyz, d.clock_bias_s[None] * C])


def trial_fields(d: TrialDraw) -> dict:
    """The per-trial fields of ``results.Results`` that come from the draws.

    Parameters
    ----------
    d : TrialDraw
        The trial's draws.

    Returns
    -------
    dict
        {field name: array}.
    """
    return {"ue_xyz": d.ue_xyz, "clock_bias_s": d.clock_bias_s, "bs_index": d.bs_index, "los": d.los,
            "link_snr_db": d.link_snr_db, "link_sinr_db": d.link_sinr_db}


def grid_trial_fn(e: Experiment, dep: deployment.Deployment):
    """The traceable per-trial function of the grid search.

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.

    Returns
    -------
    callable
        (trial key, trial index, ext_center (S, J, 4) m) → the trial's fields of ``results.Results``.  ext_center is the window
        centre of every (SNR, M) in the non-truth centrings: the trial's prior centre, or its OTDoA fixes.
    """
    draw = draw_fn(e, dep)
    cfg = e.receiver_search()
    # one window centre for every M only when it is the truth: the experiment this function is built from
    # (``program_config``) names both external centrings "prior", and the OTDoA fixes differ between the M values
    shared_centre = e.receiver.centring == "truth"

    def one(key, t, ext_center):
        d = draw(key, t)
        c0 = truth_center(d)  # read in centring "truth" only
        bs = d.bs_xyz
        parts, windows = receiver.grid_windows(d, cfg)
        if shared_centre and parts is not None and not cfg.polish:  # every SNR's first level in one lookup
            start = grid_search.grid_window(bs, c0, cfg, PAPER)
            a, b = receiver.noise_scales(d)
            r = receiver.mixed_grid_fixes(parts(start), start, a, b, bs, c0, cfg, e.receiver.m_values, PAPER)
            return scored_fields(d, r, jnp.broadcast_to(c0, r.q.shape))

        def per_snr(s):
            g = correlogram.ls_spectrum(receiver.spectrum_at(d, s), d.prs)  # read by the polish only
            if shared_centre:  # one window and one first level for every M
                corr = windows(s, grid_search.grid_window(bs, c0, cfg, PAPER))
                r = grid_search.nested_grid_fixes(corr, g, bs, c0, cfg, e.receiver.m_values, PAPER)
                return r, jnp.broadcast_to(c0, (len(e.receiver.m_values), 4))
            fixes = []
            for j, m in enumerate(e.receiver.m_values):
                c = ext_center[s, j]
                corr = grid_search.first_rows(windows(s, grid_search.grid_window(bs, c, cfg, PAPER)), m)
                fixes.append(receiver.fix_in_window(g[:m], bs[:m], c, cfg, PAPER, corr=corr))
            return jax.tree.map(lambda *f: jnp.stack(f), *fixes), ext_center[s]

        r, centers = jax.lax.map(per_snr, jnp.arange(d.n_snr))  # (S, J, ...)
        return scored_fields(d, r, centers)

    return one


def scored_fields(d: TrialDraw, r: WindowFix, centers) -> dict:
    """The trial's fields of ``results.Results`` from its draws, fixes and window centres, scored against the truth.

    Parameters
    ----------
    d : TrialDraw
        The trial's draws.
    r : WindowFix
        Its fixes, arrays (S, J, ...).
    centers : float (S, J, 4)
        The window centres, metres.

    Returns
    -------
    dict
        {field name: array}.
    """
    return trial_fields(d) | {"est_xyz": r.q[..., :3], "est_bias_s": r.q[..., 3] / C,
                              "error_m": jnp.linalg.norm(r.q[..., :2] - d.ue_xyz[:2], axis=-1),
                              "center_xyz": centers[..., :3], "edge": r.edge, "gap": r.gap,
                              "certified": r.certified}


def bnb_prep_fn(e: Experiment, dep: deployment.Deployment):
    """The certified search's first program, jitted: only the windows, not the whole correlograms, go to ``bnb_fix_fn``.

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.

    Returns
    -------
    callable
        (trial key, trial index, window, window centres ext (S, J, 4) m of the non-truth centrings) → (the trial's draw fields
        (``trial_fields``), BS positions (I, 3) m, the window centres (S, J, 4) m, the part of each BS's spline
        correlogram each window reaches (``certified_window``: coefficients (S, J, I, cells + 3) and their first knots
        (S, J, I))).
    """
    draw = draw_fn(e, dep)
    cfg = e.receiver_search()

    def bnb_prep(key, t, window, ext):
        d = draw(key, t)
        centers = jnp.broadcast_to(truth_center(d), ext.shape) if e.receiver.centring == "truth" else ext
        correlograms = receiver.spline_correlograms(d, cfg, window)

        def per_snr(a):
            s, cen = a
            coef = correlograms(s)
            return jax.vmap(lambda c: certified_window(e, coef, d.bs_xyz, c, cfg, window))(cen)

        sls, starts = jax.lax.map(per_snr, (jnp.arange(d.n_snr), centers))  # (S, J, I, ...)
        return trial_fields(d), d.bs_xyz, centers, sls, starts

    return jax.jit(bnb_prep)


def bnb_fix_fn(cfg: SearchConfig, m_values: tuple[int, ...]):
    """The certified search's fixes of one trial, jitted: one program per search, M values and number of SNRs.

    Parameters
    ----------
    cfg : SearchConfig
        The receiver's search without its window L (``program_config`` "bnb_fix").
    m_values : tuple of int
        The numbers M of nearest BSs to fix with.

    Returns
    -------
    callable
        (BS positions (I, 3) m, window centres (S, J, 4) m, the windows of the spline correlograms (``receiver_window``:
        (S, J, I, cells + 3) and (S, J, I))) → ``WindowFix`` (S, J, ...), with the M nearest BSs for each M of
        ``m_values``.
    """
    def certified_fix(bs, centers, sls, starts):
        def per_snr(a):
            cen, sl, st = a
            fixes = [receiver.fix_in_window(None, bs[:m], cen[j], cfg, PAPER, corr=(sl[j, :m], st[j, :m]))
                     for j, m in enumerate(m_values)]
            return jax.tree.map(lambda *f: jnp.stack(f), *fixes)

        return jax.lax.map(per_snr, (centers, sls, starts))

    return jax.jit(certified_fix)


@jax.jit
def score(q, ue):
    """Fixes' clock bias and horizontal error against the true UE position, in XLA.

    Scored as ``scored_fields`` scores them (NumPy rounds the same expressions differently in the last bit).

    Parameters
    ----------
    q : float (..., 4)
        Fixes (x, y, z, c δt), metres.
    ue : float (3,)
        The true UE position, metres.

    Returns
    -------
    bias_s : float (...)
        The clock bias, seconds.
    error_m : float (...)
        The horizontal error, metres.
    """
    return q[..., 3] / C, jnp.linalg.norm(q[..., :2] - ue[:2], axis=-1)


def prior_fn(e: Experiment, dep: deployment.Deployment):
    """Traceable (key, trial index) → the trial's "prior" window centre (``draw.prior_center``).

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.

    Returns
    -------
    callable
        (key, t) → float (4,), metres.
    """
    draw = draw_fn(e, dep)
    return lambda key, t: prior_center(e, draw(key, t).ue_xyz, key)


def toa_fn(e: Experiment, dep: deployment.Deployment):
    """Traceable (key, trial index) → the ToAs of every link with each OTDoA detector (OTDoA step 1).

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.

    Returns
    -------
    callable
        (key, t) → (ToAs (S, D, I) in seconds with each detector of ``OTDOA_DETECTORS``, the true UE position (3,) m (to
        score the fixes), the indices (I,) of the nearest BSs); with ``otdoa_nlos``, (ToAs, σ (S, I) in metres of
        eq. (O1), position, indices).
    """
    draw = draw_fn(e, dep)
    with_sigma = e.receiver.otdoa_nlos

    def one(key, t):
        d = draw(key, t)

        def per_snr(s):
            g = correlogram.ls_spectrum(receiver.spectrum_at(d, s), d.prs)
            toas = jnp.stack([otdoa.toa_from_spectrum(g, meth, OTDOA_UPSAMPLE, OTDOA_THRESHOLD_DB, OTDOA_MAX_LEAD,
                                                      PAPER.sample_period_s) for meth in OTDOA_DETECTORS])
            first, peak = (toas[OTDOA_DETECTORS.index(k)] for k in ("first_path", "peak"))
            return ((toas, otdoa_nlos.sigma_of_spectrum(g, d.prs, first, peak, OTDOA_UPSAMPLE, PAPER.scs_hz))
                    if with_sigma else toas)

        out = jax.lax.map(per_snr, jnp.arange(d.n_snr))
        return (*out, d.ue_xyz, d.bs_index) if with_sigma else (out, d.ue_xyz, d.bs_index)

    return one


def otdoa_fixes(e: Experiment, dep: deployment.Deployment, toas: np.ndarray, ue: np.ndarray, idx: np.ndarray,
                solvers: dict) -> dict:
    """OTDoA fixes from a chunk's ToAs (cvxpy, one compiled problem per M), flagged, never dropped.

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.
    toas : numpy.ndarray, float (T, S, D, I)
        The ToAs of every detector, seconds.
    ue : numpy.ndarray, float (T, 3)
        The true UE positions, metres (for the error only).
    idx : numpy.ndarray, int (T, I)
        The nearest BSs' indices.
    solvers : dict
        {M: ``otdoa.Solver``}.

    Returns
    -------
    dict
        The OTDoA fields of ``results.Results``.
    """
    n_t, n_s, n_d = toas.shape[:3]
    xyz = np.full((n_t, n_s, n_d, len(e.receiver.m_values), 3), np.nan)
    ok = np.zeros((n_t, n_s, n_d, len(e.receiver.m_values)), dtype=bool)
    for t in range(n_t):
        for j, m in enumerate(e.receiver.m_values):
            bs = dep.bs_xyz[idx[t, :m]]
            for s in range(n_s):
                for k in range(n_d):
                    f = solvers[m].solve(bs, toas[t, s, k, :m], float(ue[t, 2]))
                    xyz[t, s, k, j], ok[t, s, k, j] = f.xyz, f.ok
    err = np.linalg.norm(xyz[..., :2] - ue[:, None, None, None, :2], axis=-1)
    return {"otdoa_toa_s": toas, "otdoa_xyz": xyz, "otdoa_error_m": err, "otdoa_ok": ok}


def otdoa_centers(e: Experiment, dep: deployment.Deployment, ot: dict, idx: np.ndarray) -> np.ndarray:
    """Centring "otdoa": the window centre of each (trial, SNR, M) is the OTDoA fix of detector ``toa_method``.

    At the known UE height with c δt = 0 (clock_window "free": ``toa_fit.implied_bias_m``); where that fix is not
    finite (solver failure), the centroid of the M BSs used (known to the receiver).

    Parameters
    ----------
    e : Experiment
        The experiment.
    dep : deployment.Deployment
        Its deployment.
    ot : dict
        The OTDoA fields (``otdoa_fixes``).
    idx : numpy.ndarray, int (T, I)
        The nearest BSs' indices.

    Returns
    -------
    numpy.ndarray, float (T, S, J, 4)
        The centres, metres.
    """
    k = OTDOA_DETECTORS.index(e.receiver.toa_method)
    xyz = ot["otdoa_xyz"][:, :, k]  # (T, S, J, 3)
    out = np.zeros(xyz.shape[:3] + (4,))
    out[..., :3] = xyz
    out[..., 2] = dep.ue_height_m
    for j, m in enumerate(e.receiver.m_values):
        bs = dep.bs_xyz[idx[:, :m]][:, None]  # (T, 1, m, 3)
        bad = ~np.all(np.isfinite(xyz[:, :, j]), axis=-1, keepdims=True)  # (T, S, 1)
        out[:, :, j, :2] = np.where(bad, bs[..., :2].mean(axis=2), out[:, :, j, :2])
        if e.receiver.clock_window == "free":  # no clock prior: the c δt that the centre and its ToAs imply
            out[:, :, j, 3] = np.nan_to_num(toa_fit.implied_bias_m(bs, ot["otdoa_toa_s"][:, :, k, :m], out[:, :, j]))
    return out


@dataclass(frozen=True)
class TrialExample:
    """One trial at one SNR index exactly as the receivers see it, as NumPy arrays (``example``).

    The fields of ``TrialDraw`` without the unit noise, the SNR and SINR at that index only, and the received samples.

    Attributes
    ----------
    ue_xyz : float (3,)
        The UE position, metres.
    clock_bias_s : float ()
        The clock bias δt, seconds.
    bs_index : int (I,)
        The BSs' deployment indices.
    bs_xyz : float (I, 3)
        The BSs' positions, metres.
    los : bool (I,)
        The links' LoS states.
    prs : complex (I, N)
        Pilots.
    gains : complex (I, L)
        Tap gains.
    delays_s : float (I, L)
        Tap delays, seconds.
    y : complex (I, N)
        The received samples (the inverse DFT of ``receiver.spectrum_at``; in units of the noise where the links'
        powers differ).
    y0 : complex (I, N)
        The links' noise-free samples at unit power.
    link_snr_db, link_sinr_db : float (I,)
        Per-sample SNR and SINR of each link at that index, dB.
    reuse : ReuseDraw or None
        With PRS reuse (its ``co_channel.snr_db`` (X,) at that index only), else None.
    """

    ue_xyz: np.ndarray
    clock_bias_s: np.ndarray
    bs_index: np.ndarray
    bs_xyz: np.ndarray
    los: np.ndarray
    prs: np.ndarray
    gains: np.ndarray
    delays_s: np.ndarray
    y: np.ndarray
    y0: np.ndarray
    link_snr_db: np.ndarray
    link_sinr_db: np.ndarray
    reuse: ReuseDraw | None


def example(e: Experiment, trial: int, snr_index: int = 0) -> TrialExample:
    """The draws and received samples of trial ``trial`` at SNR index ``snr_index``.

    From the engine's own key and draw (``trial_draw.trial_key``, ``draw.draw_fn``, ``receiver.spectrum_at``).

    Parameters
    ----------
    e : Experiment
        The experiment.
    trial : int
        The trial, 0 to ``n_trials`` − 1.
    snr_index : int
        The SNR index, 0 to ``n_snr`` − 1.

    Returns
    -------
    TrialExample
        The trial as the receivers see it.

    Raises
    ------
    ValueError
        When ``trial`` or ``snr_index`` is out of range.
    """
    dep = e.load_deployment()
    _checks.integer("trial", trial, 0, e.run.n_trials - 1)
    _checks.integer("snr_index", snr_index, 0, e.n_snr - 1)
    d = draw_fn(e, dep)(trial_key(e.run.seed, trial), trial)
    reuse = None
    if d.reuse is not None:
        x = d.reuse.co_channel
        if x is not None:
            x = CoChannelDraw(res=np.asarray(x.res), prs=np.asarray(x.prs), y0=np.asarray(x.y0),
                              snr_db=np.asarray(x.snr_db)[snr_index])
        reuse = ReuseDraw(res=np.asarray(d.reuse.res), co_channel=x, n_res=d.reuse.n_res)
    a = lambda v: np.asarray(v)
    return TrialExample(ue_xyz=a(d.ue_xyz), clock_bias_s=a(d.clock_bias_s), bs_index=a(d.bs_index),
                        bs_xyz=a(d.bs_xyz), los=a(d.los), prs=a(d.prs), gains=a(d.gains), delays_s=a(d.delays_s),
                        y=a(signal.ofdm_symbol(receiver.spectrum_at(d, snr_index))), y0=a(signal.ofdm_symbol(d.y0)),
                        link_snr_db=a(d.link_snr_db)[snr_index], link_sinr_db=a(d.link_sinr_db)[snr_index],
                        reuse=reuse)


def certified_window(e: Experiment, coef, bs_xyz, center, cfg: SearchConfig, window):
    """The window of the spline correlograms that experiment e's certified search reads: ``marginal_window`` for the
    NLoS-aware DPE (``dpe_nlos.marginal_window``; ``Receiver.dpe_nlos``, the excess-delay law it assumes, ``Experiment.excess_law``, to
    ``dpe_nlos.CLOCK_NLOS_QUANTILE``, as the clock window), else ``spline_bounds.spline_window``.  Traceable.

    Parameters
    ----------
    e : Experiment
        The experiment.
    coef, bs_xyz, center, cfg, window
        As ``dpe_nlos.marginal_window``'s.

    Returns
    -------
    coefficients : float (M, cells + 3)
    start : int (M,)
    """
    if not e.receiver.dpe_nlos:
        return spline_window(coef, bs_xyz, center, cfg, PAPER)
    return dpe_nlos.marginal_window(coef, bs_xyz, center, cfg, window, *e.excess_law(), dpe_nlos.CLOCK_NLOS_QUANTILE,
                                    PAPER)
