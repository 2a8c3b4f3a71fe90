"""Where the ray-traced city's position error comes from: the NLoS bias, which a genie first path removes, and the
multipath the receivers meet on LoS links.

On the stored trials of a city experiment (``city_study.city_fig10(m, "otdoa")``), trial t's link m is a traced link
of the city (``trial_links``) with a first-path excess delay Δτ_m (``TracedCity.first_excess_s``: its earliest path,
or its earliest within a threshold of its strongest, the first path a first-path detector finds).  The genie
subtracts it from the first-path detector's ToA::

    τ̃_m = τ_m − Δτ_m,

and the same receivers fix from τ̃ (``genie_fixes``, ``receiver_fixes``): the OTDoA SOCP with its Gauss–Newton polish
(``otdoa.Solver``) and eq. (T1)'s ToA fit in the DPE's windows, started at that OTDoA fix (``toa_fit.fit``, as
``studies.toa_fit_errors`` runs it).  What error remains is the detector's (paths it merges within a pulse, or a
first path other than the traced one, and noise); what the genie removes is the NLoS bias (``genie_split``).  Which
Δτ it subtracts matters: a link's earliest path often lies far below its strongest, where the detector does not look.
The genie reads the traced paths, which no receiver knows: it is a bound, not a receiver.

Where every link is LoS there is no bias to remove, and the DPE and OTDoA differ by how each reads the same
multipath: OTDoA's first-path detector takes the earliest peak within its threshold, the DPE's cost integrates the
energy in an L-tap window (``search_config.DEFAULT_TAPS``) after each hypothesised ToA (eq. (10)), multipath included.
``los_trials`` gives both receivers' errors there, each link's pseudorange error under each (the truth's range and
clock bias subtracted), and each link's K-factor and delay spread (``city_channel``).
Units: metres, seconds, dB.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..common import _checks
from ..phy.nr import C, PAPER
from ..receivers import otdoa, toa_fit
from ..city import dataset as city_paths
from ..simulation import traced_draw
from ..simulation.experiment import OTDOA_DETECTORS, Experiment
from . import city as city_study, city_channel


def trial_links(city: city_paths.TracedCity, e: Experiment, res) -> np.ndarray:
    """Each trial's links as rows of the city's link arrays: trial t is the population's UE t with its I strongest
    heard links (``city_draw.traced_links``), checked against ``res`` by ``city_study.link_populations``.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city (``e``'s deployment's).
    e : Experiment
        A city experiment (``city_study.city_fig10``).
    res : results.Results
        Its run (``engine.run(e)``), or anything with its ``ue_xyz`` (T, 3), ``bs_index`` (T, I) and ``los`` (T, I).

    Returns
    -------
    int (T, I)
        Link indices (rows of ``city.excess_s``, ``city.gains``), in the order of ``res.bs_index``.

    Raises
    ------
    ValueError
        When ``res``'s trials are not the population's (another city or experiment).
    """

    heard = city_study.link_populations(city, e, res)["heard"]
    bs = np.asarray(res.bs_index)
    ue = traced_draw.traced_links(city, bs.shape[1], heard).ue_index[:len(bs)]
    return city.link_table()[ue[:, None], bs]


@dataclass(frozen=True)
class Fixes:
    """The first-path receivers' fixes from one set of ToAs (``receiver_fixes``).

    Attributes
    ----------
    otdoa_xy : float (T, 2)
        The OTDoA fixes, metres (NaN where the solver failed).
    otdoa_ok : bool (T,)
        ``otdoa.Fix.ok``: the fix is trusted.
    fit_xy : float (T, 2)
        Eq. (T1)'s ToA fits, metres.
    """

    otdoa_xy: np.ndarray
    otdoa_ok: np.ndarray
    fit_xy: np.ndarray


def receiver_fixes(bs_xyz, toa_s, ue_z, bias_half_m: float = math.inf, half_width_m: float = math.inf) -> Fixes:
    """The OTDoA fix (``otdoa.Solver.solve``, polished) and eq. (T1)'s ToA fit started at it (at the BSs' centroid
    where it failed), as the engine and ``studies.toa_fit_errors`` compute them, for T trials.

    Parameters
    ----------
    bs_xyz : float (T, M, 3)
        Each trial's BSs, metres, in the run's order (the first the reference of ``otdoa.Solver``), M ≥ 3.
    toa_s : float (T, M)
        Their ToAs, seconds (clock bias included).
    ue_z : float or float (T,)
        The known UE height, metres.
    bias_half_m : float
        The ToA fit's clock window B, metres, > 0 (inf: no clock prior).
    half_width_m : float
        The ToA fit's position window H around the OTDoA fix, metres, > 0 (inf: none).

    Returns
    -------
    Fixes

    Raises
    ------
    ValueError
        When the shapes do not match, a value is not finite, a window is not positive, or a trial's BSs are
        collinear (``otdoa.check_geometry``).
    """
    bs, toa = np.asarray(bs_xyz, dtype=np.float64), np.asarray(toa_s, dtype=np.float64)
    if bs.ndim != 3 or bs.shape[2] != 3 or bs.shape[1] < 3:
        raise ValueError(f"bs_xyz must be (T, M, 3) metres with M ≥ 3, got shape {bs.shape}")
    if toa.shape != bs.shape[:2] or not np.all(np.isfinite(toa)):
        raise ValueError(f"toa_s must be finite ToAs of shape {bs.shape[:2]} (T, M), seconds, got {toa.shape}")
    z = np.broadcast_to(np.asarray(ue_z, dtype=np.float64), bs.shape[:1])
    solver = otdoa.Solver(bs.shape[1])
    xy, ok = np.full((len(bs), 2), np.nan), np.zeros(len(bs), dtype=bool)
    for t in range(len(bs)):
        f = solver.solve(bs[t], toa[t], float(z[t]))
        xy[t], ok[t] = f.xyz[:2], f.ok
    start = np.where(np.isfinite(xy), xy, bs[..., :2].mean(axis=1))
    return Fixes(otdoa_xy=xy, otdoa_ok=ok, fit_xy=toa_fit.fit(bs, toa, z, start, bias_half_m, half_width_m).xy)


def genie_fixes(bs_xyz, toa_s, excess_s, ue_z, bias_half_m: float = math.inf,
                half_width_m: float = math.inf) -> tuple[Fixes, Fixes]:
    """The first-path receivers' fixes (``receiver_fixes``) from the ToAs as detected, τ_m, and from the genie's,
    τ̃_m = τ_m − Δτ_m (module docstring).

    Parameters
    ----------
    bs_xyz : float (T, M, 3)
        Each trial's BSs, metres, the reference first, M ≥ 3.
    toa_s : float (T, M)
        Their first-path ToAs τ_m, seconds (clock bias included).
    excess_s : float (T, M)
        Each link's first-path excess delay Δτ_m, seconds (0 on a LoS link, to the tracer's rounding: below 1 ps).
    ue_z : float or float (T,)
        The known UE height, metres.
    bias_half_m, half_width_m : float
        The ToA fit's windows, as ``receiver_fixes``'s.

    Returns
    -------
    detected, genie : Fixes
        From τ and from τ̃.

    Raises
    ------
    ValueError
        When excess_s is not finite or not of toa_s's shape, or as ``receiver_fixes`` raises.
    """
    toa, dt = np.asarray(toa_s, dtype=np.float64), np.asarray(excess_s, dtype=np.float64)
    if dt.shape != toa.shape or not np.all(np.isfinite(dt)):
        raise ValueError(f"excess_s must be finite delays, seconds, of toa_s's shape {toa.shape}, got {dt.shape}")
    return (receiver_fixes(bs_xyz, toa, ue_z, bias_half_m, half_width_m),
            receiver_fixes(bs_xyz, toa - dt, ue_z, bias_half_m, half_width_m))


@dataclass(frozen=True)
class GenieSplit:
    """The first-path receivers' errors on a city experiment's trials, with and without the genie first path
    (``genie_split``).

    Attributes
    ----------
    threshold_db : float or None
        The first path the genie subtracts: the earliest within threshold_db of the link's strongest path; None: the
        earliest traced path.
    excess_s : float (T, M)
        The subtracted Δτ, seconds (0 on a LoS link's earliest path).
    n_nlos : int (T,)
        Each trial's NLoS links.
    otdoa_m, genie_otdoa_m : float (T,)
        The first-path OTDoA's horizontal error from the ToAs as detected, and from the genie's, metres.
    fit_m, genie_fit_m : float (T,)
        The same for eq. (T1)'s first-path ToA fit in the DPE's windows.
    refix_gap_m : float
        The largest distance between the OTDoA fixes recomputed here from the stored ToAs and the stored ones
        (``otdoa.POSITION_ATOL_M`` is what the store allows between CPUs), metres.
    """

    threshold_db: float | None
    excess_s: np.ndarray
    n_nlos: np.ndarray
    otdoa_m: np.ndarray
    genie_otdoa_m: np.ndarray
    fit_m: np.ndarray
    genie_fit_m: np.ndarray
    refix_gap_m: float


def genie_split(city: city_paths.TracedCity, e: Experiment, res, threshold_db: float | None = None,
                s: int = 0) -> GenieSplit:
    """The first-path OTDoA and ToA fit on ``res``'s trials from the ToAs as detected and from the genie's
    τ̃_m = τ_m − Δτ_m (module docstring), with M = max(m_values) links.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    e : Experiment
        A city experiment centred on the OTDoA fix (``city_study.city_fig10(m, "otdoa")``).
    res : results.Results
        Its run (``engine.run(e)``): ``otdoa_toa_s`` (T, S, D, I), ``otdoa_xyz``, ``bs_index``, ``ue_xyz``, ``los``.
    threshold_db : float or None
        Δτ is the earliest path within threshold_db (dB, ≤ 0) of the link's strongest
        (``city_study.FIRST_PATH_THRESHOLD_DB`` is the detector's); None: the earliest.
    s : int
        The SNR index.

    Returns
    -------
    GenieSplit

    Raises
    ------
    ValueError
        When ``res`` is not a run of ``e`` on the city, threshold_db is above 0 dB, or s is not an SNR index.
    """
    toa_all = np.asarray(res.otdoa_toa_s)
    s = _checks.integer("s", s, 0, toa_all.shape[1] - 1)
    rows = trial_links(city, e, res)
    m = max(e.receiver.m_values)
    j, k = list(e.receiver.m_values).index(m), OTDOA_DETECTORS.index("first_path")
    dt = city.first_excess_s(threshold_db)[rows[:, :m]]
    bs = e.load_deployment().bs_xyz[np.asarray(res.bs_index)[:, :m]]
    toa, ue = toa_all[:, s, k, :m].astype(np.float64), np.asarray(res.ue_xyz, dtype=np.float64)
    half_b, half_w = toa_fit.dpe_windows(e)
    raw, genie = genie_fixes(bs, toa, dt, ue[:, 2], half_b, half_w)
    err = lambda xy: np.linalg.norm(xy - ue[:, :2], axis=-1)  # noqa: E731
    stored = np.asarray(res.otdoa_xyz)[:, s, k, j, :2]
    return GenieSplit(threshold_db=None if threshold_db is None else float(threshold_db), excess_s=dt,
                      n_nlos=(~city.los[rows[:, :m]]).sum(axis=1), otdoa_m=err(raw.otdoa_xy),
                      genie_otdoa_m=err(genie.otdoa_xy), fit_m=err(raw.fit_xy), genie_fit_m=err(genie.fit_xy),
                      refix_gap_m=float(np.nanmax(np.linalg.norm(raw.otdoa_xy - stored, axis=-1))))


@dataclass(frozen=True)
class LosTrials:
    """The trials whose M links are all LoS: both receivers' errors and the links' multipath (``los_trials``).

    Attributes
    ----------
    trial : int (n,)
        The trials' indices in the run.
    dpe_m : float (n,)
        The DPE's horizontal error, metres.
    otdoa_m, fit_m : float (n,)
        The first-path OTDoA's and eq. (T1)'s first-path ToA fit's, metres.
    dpe_range_m, otdoa_range_m : float (n, M)
        Each link's pseudorange error, metres: the DPE fix's ‖p̂ − b_m‖ + c δ̂t, and the first-path detector's c τ_m,
        less the truth's ‖p − b_m‖ + c δt (negative: early).
    k_db : float (n, M)
        Each link's K-factor over its kept paths (``city_channel.k_factor_db``), dB.
    ds_s : float (n, M)
        Each link's RMS delay spread over its kept paths (``city_channel.delay_spread_s``), seconds.
    window_s : float
        The DPE's window, L taps of T_s, seconds.
    """

    trial: np.ndarray
    dpe_m: np.ndarray
    otdoa_m: np.ndarray
    fit_m: np.ndarray
    dpe_range_m: np.ndarray
    otdoa_range_m: np.ndarray
    k_db: np.ndarray
    ds_s: np.ndarray
    window_s: float


def los_trials(city: city_paths.TracedCity, e: Experiment, res, s: int = 0) -> LosTrials:
    """The DPE and the first-path OTDoA on ``res``'s trials with M = max(m_values) LoS links: their errors, each
    link's pseudorange error, and each link's K-factor and delay spread.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    e : Experiment
        A city experiment centred on the OTDoA fix (``city_study.city_fig10(m, "otdoa")``).
    res : results.Results
        Its run (``engine.run(e)``).
    s : int
        The SNR index.

    Returns
    -------
    LosTrials

    Raises
    ------
    ValueError
        When ``res`` is not a run of ``e`` on the city, or s is not an SNR index.
    """
    s = _checks.integer("s", s, 0, np.asarray(res.error_m).shape[1] - 1)
    m = max(e.receiver.m_values)
    j, k = list(e.receiver.m_values).index(m), OTDOA_DETECTORS.index("first_path")
    rows = trial_links(city, e, res)[:, :m]
    t = np.nonzero(city.los[rows].all(axis=1))[0]
    r = rows[t]
    bs = e.load_deployment().bs_xyz[np.asarray(res.bs_index)[t, :m]]
    ue = np.asarray(res.ue_xyz, dtype=np.float64)[t]
    toa = np.asarray(res.otdoa_toa_s)[t, s, k, :m].astype(np.float64)
    fit = receiver_fixes(bs, toa, ue[:, 2], *toa_fit.dpe_windows(e)).fit_xy
    rho = np.linalg.norm(ue[:, None] - bs, axis=-1) + C * np.asarray(res.clock_bias_s)[t, None]
    est = np.asarray(res.est_xyz)[t, s, j, None, :3]
    dpe_rho = np.linalg.norm(est - bs, axis=-1) + C * np.asarray(res.est_bias_s)[t, s, j, None]
    ds = city_channel.delay_spread_s(city.excess_s[r.ravel()], city.gains[r.ravel()]).reshape(r.shape)
    kf = city_channel.k_factor_db(city.gains[r.ravel()], city.los[r.ravel()]).reshape(r.shape)
    return LosTrials(trial=t, dpe_m=np.asarray(res.error_m)[t, s, j], otdoa_m=np.asarray(res.otdoa_error_m)[t, s, k, j],
                     fit_m=np.linalg.norm(fit - ue[:, :2], axis=-1), dpe_range_m=dpe_rho - rho,
                     otdoa_range_m=C * toa - rho, k_db=kf, ds_s=ds,
                     window_s=e.receiver.search.n_taps * PAPER.sample_period_s)
