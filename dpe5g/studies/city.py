"""The ray-traced city's experiments (ours, beyond the paper): Fig. 10's receivers on Sionna RT's paths.

Each is ``paper.fig10``'s experiment with LoS from eq. (11) and one change: the channel is the traced city's
(``Scenario.channel`` "traced", ``traced_draw``), so each trial is one traced outdoor UE, its links the BSs it hears
strongest.  The honest receivers (the DPE centred on the OTDoA fix, which runs on the same signals) and, as a labelled
comparison, the paper's DPE centred on the truth.  And what the city says of the stochastic model: its NLoS
first-path excess delays against TR 38.901's log-normal (``excess_fit``), and its LoS share against eq. (11)
(``los_by_distance``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy import stats

from ..phy import propagation
from ..city import dataset as city_paths
from ..common import locations
from ..simulation import engine, traced_draw, trials
from ..simulation.experiment import OTDOA_DETECTORS, Experiment
from . import choices, intervals, paper

#: the traced city (its deployment's and its dataset's name): Sionna RT's "munich" scene (``city_trace.CitySpec``); every
#: experiment of this module takes ``city``, another stored city (the second city, ``city_second``), this by default
CITY = "munich"
#: the numbers M of links: Fig. 10's 4, and 6
CITY_M = (4, 6)
#: trials of the city experiments with M links: the first CITY_TRIALS[M] UEs that hear M BSs (of Munich's 1808 and
#: 307), or every one where fewer do (``city_trials``)
CITY_TRIALS = {4: 1000, 6: 300}
#: the centrings run: the honest DPE (on the OTDoA fix, with both OTDoA detectors) and the paper's, on the truth
CITY_CENTRINGS = ("otdoa", "truth")
#: the UE clock's σ the city's honest DPE is told (s), swept: the clock model's 5 ns (every other run's), 30 ns, 100 ns,
#: and None, no clock prior (``city_clock``); the OTDoA family's ToA fits get the same window (``clock_families``)
CITY_CLOCK_PRIORS_S = (5e-9, 30e-9, 100e-9, None)


def city_fig10(m: int, centring: str, n_trials: int | None = None, city: str = CITY) -> Experiment:
    """Fig. 10's experiment (LoS from eq. (11), link-budget SNR) on the traced city, with M = m links.

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    centring : str
        ``CITY_CENTRINGS``.
    n_trials : int or None
        Trials: the first n_trials UEs that hear m BSs; None: ``city_trials(m, city)``.
    city : str
        The stored city's name.

    Returns
    -------
    Experiment
        "city-{city}-m{m}-{centring}".
    """
    e = paper.fig10(city_trials(m, city) if n_trials is None else n_trials)[("pr_los", centring)]
    return e.replace(name=f"city-{city}-m{m}-{centring}", deployment=city, channel="traced", m_values=(m,))


def city_trials(m: int, city: str = CITY) -> int:
    """The trials of ``city``'s experiments with m links: ``CITY_TRIALS[m]``, or the UEs that hear m BSs where fewer
    do (counted once per process for each stored version of the city).

    Parameters
    ----------
    m : int
        One of ``CITY_M``.
    city : str
        The stored city's name.

    Returns
    -------
    int
    """
    return _heard_trials(m, city, str(locations.cities_dir()), city_paths.read_record(city)["record_checksum"])


@lru_cache(maxsize=None)
def _heard_trials(m: int, city: str, folder: str, record_checksum: str) -> int:
    """``city_trials`` of the city whose record, in ``folder``, has ``record_checksum`` (the cache's key)."""
    return min(CITY_TRIALS[m], stored_city_fig10(city, m).run.n_trials)


def city_nlos(m: int, n_trials: int | None = None, city: str = CITY) -> dict:
    """The NLoS-aware receivers on the trials of the city's honest experiment (``city_fig10(m, "otdoa")``).

    Each assumes TR 38.901's UMi excess delay (``Receiver.nlos_prior`` "umi": the city's delays have no law a
    receiver could know), and eq. (11)'s LoS probability.

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    n_trials : int or None
        As ``city_fig10``'s.
    city : str
        As ``city_fig10``'s.

    Returns
    -------
    dict
        {"ot": the NLoS-aware OTDoA (``otdoa_nlos``), "wide": the naive DPE in the clock window that covers the
        delay ("clock_nlos"), "aware": the NLoS-aware DPE (``dpe_nlos``)}, each named as the honest experiment with
        "-nlos-otdoa", "-clock-nlos" or "-nlos-dpe" added.
    """
    e = city_fig10(m, "otdoa", n_trials, city)
    wide = e.replace(name=f"{e.run.name}-clock-nlos", clock_window="clock_nlos", nlos_prior="umi")
    return {"ot": e.replace(name=f"{e.run.name}-nlos-otdoa", otdoa_nlos=True), "wide": wide,
            "aware": wide.replace(name=f"{e.run.name}-nlos-dpe", dpe_nlos=True)}


def city_families(m: int, n_trials: int | None = None, city: str = CITY) -> tuple[dict, dict]:
    """Every DPE and every OTDoA receiver on the city's trials with m links (``studies.receiver_families``).

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    n_trials : int or None
        As ``city_fig10``'s.
    city : str
        As ``city_fig10``'s.

    Returns
    -------
    dpe, otdoa : dict
        {receiver: errors (T,) m}.
    """
    return choices.receiver_families({"naive": city_fig10(m, "otdoa", n_trials, city), **city_nlos(m, n_trials, city)})


def city_clock(m: int, prior_s: float | None, n_trials: int | None = None, city: str = CITY) -> Experiment:
    """The honest DPE of ``city_fig10(m, "otdoa")`` told the UE clock to σ = prior_s, or not at all (None): its
    ``clock_twin``.

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    prior_s : float or None
        A σ of ``CITY_CLOCK_PRIORS_S``, seconds; None: no clock prior.
    n_trials : int or None
        As ``city_fig10``'s.
    city : str
        As ``city_fig10``'s.

    Returns
    -------
    Experiment
    """
    return clock_twin(city_fig10(m, "otdoa", n_trials, city), prior_s)


def clock_twin(e: Experiment, prior_s: float | None) -> Experiment:
    """The honest DPE experiment ``e`` with its DPE told the UE clock to σ = prior_s, or not at all (None).

    At the clock model's σ (``CITY_CLOCK_PRIORS_S[0]``) it is ``e``; otherwise its twin with ``Receiver.clock_prior_s``
    (name "-clock{σ in ns}ns") or clock_window "free" ("-clock-free"): the same trials and signals, only the DPE's
    clock window differs.

    Parameters
    ----------
    e : Experiment
        A city experiment centred on the OTDoA fix (``city_fig10(m, "otdoa")``, ``stored_city_fig10``).
    prior_s : float or None
        A σ, seconds; None: no clock prior.

    Returns
    -------
    Experiment
    """
    if prior_s is None:
        return e.replace(name=f"{e.run.name}-clock-free", clock_window="free")
    if prior_s == e.scenario.clock_sigma_s:
        return e
    return e.replace(name=f"{e.run.name}-clock{round(prior_s * 1e9)}ns", clock_prior_s=prior_s)


def stored_city_fig10(name: str, m: int) -> Experiment:
    """The city's honest DPE and OTDoA (``city_fig10(m, "otdoa")``, the clock model's prior) on a stored city (its
    deployment, ``deployment.builtin``): every UE of it that hears m BSs.

    Parameters
    ----------
    name : str
        A city in the store (the book's, a subset traced under other settings, a denser network, the second city).
    m : int
        The links, the UE's m strongest.

    Returns
    -------
    Experiment
        "city-{name}-m{m}-otdoa".
    """
    e = city_fig10(m, "otdoa", n_trials=1).replace(deployment=name)
    city = city_paths.load_city(name)
    n = len(traced_draw.traced_links(city, m, traced_draw.heard_links(e, city, e.load_deployment())).ue_index)
    return e.replace(name=f"city-{name}-m{m}-otdoa", n_trials=n)


def same_clock_families(e: Experiment) -> tuple[dict, dict]:
    """The naive DPE of ``e`` and every OTDoA receiver on its trials with the DPE's knowledge of the clock.

    Parameters
    ----------
    e : Experiment
        A city experiment centred on the OTDoA fix (``stored_city_fig10``, or its ``clock_twin``); run or loaded.

    Returns
    -------
    dpe, otdoa : dict
        {"naive DPE": errors (T,) m}; {"first-path OTDoA", "strongest-peak OTDoA", and the ToA fits of eq. (T1) in
        the DPE's windows (``choices.toa_fit_errors``): errors (T,) m}.
    """
    res = engine.run(e, progress=False)
    err = {det: res.otdoa_error_m[:, 0, k, 0] for k, det in enumerate(OTDOA_DETECTORS)}
    otdoa = {"first-path OTDoA": err["first_path"], "strongest-peak OTDoA": err["peak"]}
    return {"naive DPE": res.error_m[:, 0, 0]}, otdoa | {k: v[:, 0] for k, v in choices.toa_fit_errors(res).items()}


def heard_per_ue(city: city_paths.TracedCity, m: int = CITY_M[0]) -> np.ndarray:
    """How many BSs each UE of ``city`` hears (``traced_draw.heard_links``) under the city experiment's link budget.

    Parameters
    ----------
    city : city_paths.TracedCity
        A stored city.
    m : int
        The links of the experiment whose budget and detection threshold are read (``city_fig10``).

    Returns
    -------
    int (U,)
    """
    e = city_fig10(m, "otdoa", n_trials=1).replace(deployment=city.name)
    return np.bincount(city.link_ue[traced_draw.heard_links(e, city, e.load_deployment())], minlength=city.n_ue)


def clock_families(m: int, prior_s: float | None, n_trials: int | None = None, city: str = CITY) -> tuple[dict, dict]:
    """The DPE and OTDoA families on the city's trials with m links when the UE clock is known to σ = prior_s.

    At the clock model's σ, ``city_families``.  Otherwise the DPE family is the naive DPE of ``city_clock`` (the
    NLoS-aware DPE and the wide window were run with the clock model's prior only), the OTDoA family every OTDoA
    receiver with the ToA fits in that DPE's clock window (``studies.receiver_families``).

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    prior_s : float or None
        As ``city_clock``'s.
    n_trials : int or None
        As ``city_fig10``'s.
    city : str
        As ``city_fig10``'s.

    Returns
    -------
    dpe, otdoa : dict
        {receiver: errors (T,) m}.
    """
    if prior_s == CITY_CLOCK_PRIORS_S[0]:
        return city_families(m, n_trials, city)
    return choices.receiver_families({"naive": city_clock(m, prior_s, n_trials, city),
                                      "ot": city_nlos(m, n_trials, city)["ot"]})


def city_window(m: int, n_taps: int, n_trials: int | None = None, city: str = CITY) -> Experiment:
    """The honest DPE of ``city_fig10(m, "otdoa")`` with a receiver window of n_taps taps (eq. (10)'s L) instead of
    ``search_config.DEFAULT_TAPS``: the same trials, signals and clock prior (name "-L{n_taps}").

    Parameters
    ----------
    m : int
        The links, the UE's m strongest.
    n_taps : int
        The window L, taps.
    n_trials : int or None
        As ``city_fig10``'s.
    city : str
        As ``city_fig10``'s.

    Returns
    -------
    Experiment
    """
    e = city_fig10(m, "otdoa", n_trials, city)
    return e.replace(name=f"{e.run.name}-L{n_taps}", search=replace(e.receiver.search, n_taps=n_taps))


def all_experiments(city: str = CITY) -> list[Experiment]:
    """Every experiment of the city chapter on ``city``, at the trial counts it reads.

    Parameters
    ----------
    city : str
        The stored city's name.

    Returns
    -------
    list of Experiment
    """
    return ([city_fig10(m, c, city=city) for m in CITY_M for c in CITY_CENTRINGS]
            + [e for m in CITY_M for e in city_nlos(m, city=city).values()]
            + [city_clock(m, p, city=city) for m in CITY_M for p in CITY_CLOCK_PRIORS_S[1:]]
            + [city_window(CITY_M[0], 1, city=city)])


#: the first path's power below the link's strongest path, dB, by which ``excess_fit`` may define a link's first path:
#: the first-path OTDoA detector's own threshold (``trials.OTDOA_THRESHOLD_DB``, which the engine passes to
#: ``otdoa.toa``), applied here to the traced paths' powers rather than to a band-limited correlogram
FIRST_PATH_THRESHOLD_DB = trials.OTDOA_THRESHOLD_DB
#: the link populations of ``link_populations``, each within the one before
POPULATIONS = ("all", "heard", "trial")


@dataclass(frozen=True)
class ExcessFit:
    """The traced NLoS links' first-path excess delay Δτ against TR 38.901 Table 7.6.9-1's log-normal.

    Attributes
    ----------
    n_links, n_ues : int
        The NLoS links fitted (with a traced path), and the UEs they belong to.
    mean_lg, std_lg : float
        Mean and standard deviation of lg(Δτ / 1 s), decades.
    mean_lg_ci : tuple of 2 float
        The 95 % bootstrap interval of mean_lg, UEs resampled (their links kept together).
    median_s : float
        The median Δτ, seconds.
    below_1ns : float
        The share of links with Δτ < 1 ns (a path diffracted round a corner just off the straight line).
    ks_p : float
        The Kolmogorov–Smirnov p-value of lg Δτ against the standard's normal (mean −7.5, σ 0.5 for UMi).
    icc : float
        The share of lg Δτ's variance between UEs (one-way intraclass correlation over UEs with two NLoS links or
        more): 0 when a UE's links are as unalike as any two links, 1 when they share one Δτ.
    icc_ci : tuple of 2 float
        Its 95 % bootstrap interval, UEs resampled (over the resamples where it is defined).
    threshold_db : float or None
        The first path's definition: the earliest path within threshold_db (dB) of the link's strongest
        (``TracedCity.first_excess_s``); None: the earliest traced path.
    """

    n_links: int
    n_ues: int
    mean_lg: float
    std_lg: float
    mean_lg_ci: tuple
    median_s: float
    below_1ns: float
    ks_p: float
    icc: float
    icc_ci: tuple
    threshold_db: float | None = None


def intraclass_correlation(values, groups) -> float:
    """One-way random-effects intraclass correlation ICC(1) of ``values`` grouped by ``groups``.

    (MSB − MSW) / (MSB + (k₀ − 1) MSW), k₀ the adjusted mean group size, over groups of two values or more; NaN
    where fewer than two groups have two values (or every value is the same).

    Parameters
    ----------
    values : float (n,)
        The values.
    groups : int (n,)
        Each value's group.

    Returns
    -------
    float
        ICC(1), in [−1/(k₀ − 1), 1], or NaN.
    """
    values, groups = np.asarray(values, float), np.asarray(groups)
    ids, inv, size = np.unique(groups, return_inverse=True, return_counts=True)
    keep = size[inv] >= 2
    ids, inv, size = np.unique(groups[keep], return_inverse=True, return_counts=True)
    x = values[keep]
    g, n = len(ids), len(x)
    if g < 2:
        return float("nan")
    means = np.bincount(inv, weights=x) / size
    msb = np.sum(size * (means - x.mean()) ** 2) / (g - 1)
    msw = np.sum((x - means[inv]) ** 2) / (n - g)
    k0 = (n - np.sum(size**2) / n) / (g - 1)
    den = msb + (k0 - 1) * msw
    return float((msb - msw) / den) if den > 0 else float("nan")


def link_mask(city: city_paths.TracedCity, links=None) -> np.ndarray:
    """``links`` as a mask over the city's links.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city, L links.
    links : bool (L,), int (n,) or None
        A mask over the links, or link indices (rows of ``city.link_table()``); None: every link.

    Returns
    -------
    bool (L,)

    Raises
    ------
    ValueError
        When a mask is not of length L, or an index is not of a link.
    """
    n = len(city.link_ue)
    if links is None:
        return np.ones(n, bool)
    a = np.asarray(links)
    if a.dtype == bool:
        if a.shape != (n,):
            raise ValueError(f"links as a mask must have shape ({n},), one per link of the city, got {a.shape}")
        return a.copy()
    if a.size and (not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() >= n):
        raise ValueError(f"links must be a bool mask or link indices in [0, {n - 1}], got {a.dtype} from {a.min()} "
                         f"to {a.max()}")
    mask = np.zeros(n, bool)
    mask[a.astype(int)] = True
    return mask


def excess_fit(city: city_paths.TracedCity, links=None, threshold_db: float | None = None, n_boot: int = 1000,
               seed: int = 0) -> ExcessFit:
    """The traced NLoS first-path excess delays of ``city``'s links ``links`` against TR 38.901's UMi log-normal.

    ``excess_fit(city)`` fits every traced NLoS link's earliest path; ``link_populations`` gives the heard links and
    the trials' links, and ``FIRST_PATH_THRESHOLD_DB`` the first path a first-path detector finds.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    links : bool (L,), int (n,) or None
        The links whose NLoS members are fitted (``link_mask``; the LoS among them are left out); None: every link.
    threshold_db : float or None
        The first path: the earliest within threshold_db (dB, ≤ 0) of the link's strongest path; None: the earliest
        (``TracedCity.first_excess_s``).
    n_boot, seed : int
        Bootstrap draws over the UEs, and their seed.

    Returns
    -------
    ExcessFit

    Raises
    ------
    ValueError
        When ``links`` has no NLoS link, or is not a mask or indices of the city's links.
    """
    umi = propagation.TR38901_EXCESS_DELAY[propagation.NLOS_EXCESS_ROW]
    nlos = link_mask(city, links) & ~city.los
    if not nlos.any():
        raise ValueError("links has no NLoS link: nothing to fit")
    dt, ue = city.first_excess_s(threshold_db)[nlos], city.link_ue[nlos]
    lg = np.log10(np.maximum(dt, 1e-12))  # a path 1 ps off the line is as good as none (1e-12: 12 decades below 1 s)
    ues = np.unique(ue)
    rows = {u: np.nonzero(ue == u)[0] for u in ues}
    rng = np.random.default_rng(seed)
    means, iccs = [], []
    for _ in range(n_boot):
        pick = rng.choice(ues, ues.size)
        idx = np.concatenate([rows[u] for u in pick])
        grp = np.repeat(np.arange(pick.size), [rows[u].size for u in pick])
        means.append(lg[idx].mean())
        iccs.append(intraclass_correlation(lg[idx], grp))
    ci = lambda a: (float(np.nanquantile(a, 0.025)), float(np.nanquantile(a, 0.975)))  # the ICC's where defined
    return ExcessFit(n_links=int(nlos.sum()), n_ues=int(ues.size), mean_lg=float(lg.mean()), std_lg=float(lg.std()),
                     mean_lg_ci=ci(means), median_s=float(np.median(dt)), below_1ns=float(np.mean(dt < 1e-9)),
                     ks_p=float(stats.kstest(lg, stats.norm(umi.mu_lg, umi.sigma_lg).cdf).pvalue),
                     icc=intraclass_correlation(lg, ue), icc_ci=ci(iccs),
                     threshold_db=None if threshold_db is None else float(threshold_db))


def link_populations(city: city_paths.TracedCity, e: Experiment, res) -> dict:
    """The city's links in three populations (``POPULATIONS``), each within the one before, LoS links included.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city (``e``'s deployment's).
    e : Experiment
        A city experiment (``city_fig10``): its link budget decides which links are heard (``city_draw.heard_links``).
    res : results.Results
        Its run (``engine.run(e)``), or anything with its ``ue_xyz`` (T, 3), ``bs_index`` (T, I) and ``los`` (T, I):
        trial t is the population's UE t (``city_draw.traced_links``), with its I strongest heard links.

    Returns
    -------
    dict
        {"all": every traced link, "heard": the links a UE hears, "trial": the T·I links of the trials}, each bool
        (L,).

    Raises
    ------
    ValueError
        When ``res``'s trials are not the population's first T UEs with their links (another city or experiment).
    """

    heard = traced_draw.heard_links(e, city, e.load_deployment())
    bs = np.asarray(res.bs_index)
    pop = traced_draw.traced_links(city, bs.shape[1], heard)
    ue = pop.ue_index[:len(bs)]
    rows = city.link_table()[ue[:, None], bs] if len(ue) == len(bs) else None
    if (rows is None or not np.array_equal(city.ue_xyz[ue], np.asarray(res.ue_xyz))
            or not np.array_equal(pop.bs_index[:len(bs)], bs) or not np.array_equal(city.los[rows], res.los)):
        raise ValueError(f"res is not a run of {e.run.name} on the city '{city.name}': its trials' UEs, BSs or LoS "
                         "states differ from the population's")
    trial = np.zeros(len(city.link_ue), bool)
    trial[rows.ravel()] = True
    return {"all": np.ones(len(city.link_ue), bool), "heard": heard, "trial": trial}


def los_shares(city: city_paths.TracedCity, populations: dict) -> dict:
    """The share of LoS links in each population, beside eq. (11)'s probability at their 2-D distances.

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    populations : dict
        {name: the population's links, ``link_mask``'s ``links``} (``link_populations``).

    Returns
    -------
    dict
        {name: {"n_links": int, "share": the LoS share of its links, "eq11": the mean of eq. (11) over them}}.
    """
    d = np.linalg.norm(city.ue_xyz[city.link_ue, :2] - city.bs_xyz[city.link_bs, :2], axis=1)
    out = {}
    for name, links in populations.items():
        m = link_mask(city, links)
        out[name] = {"n_links": int(m.sum()), "share": float(city.los[m].mean()),
                     "eq11": float(np.mean(propagation.los_probability(d[m])))}
    return out


def los_by_distance(city: city_paths.TracedCity, edges_m) -> dict:
    """The share of LoS among every (UE, BS) pair by 2-D distance, beside eq. (11)'s probability.

    A pair with no traced path counts as NLoS (its straight line is blocked: the LoS path would have been traced).

    Parameters
    ----------
    city : city_paths.TracedCity
        The traced city.
    edges_m : float (n + 1,)
        Distance bins, metres.

    Returns
    -------
    dict
        "centre_m" (n,), "share" (n,), "n_pairs" (n,), "eq11" (n,) the mean of eq. (11) over each bin's pairs.
    """
    d = np.linalg.norm(city.ue_xyz[:, None, :2] - city.bs_xyz[None, :, :2], axis=-1)
    los = np.zeros(d.shape, bool)
    los[city.link_ue, city.link_bs] = city.los
    b = np.digitize(d, edges_m) - 1
    ok = (b >= 0) & (b < len(edges_m) - 1)
    n = np.bincount(b[ok], minlength=len(edges_m) - 1)
    share = np.bincount(b[ok], weights=los[ok], minlength=len(edges_m) - 1) / np.maximum(n, 1)
    p11 = np.asarray(propagation.los_probability(d[ok]))
    eq11 = np.bincount(b[ok], weights=p11, minlength=len(edges_m) - 1) / np.maximum(n, 1)
    return {"centre_m": 0.5 * (np.asarray(edges_m[1:]) + np.asarray(edges_m[:-1])), "share": share, "n_pairs": n,
            "eq11": eq11}


def summary(city: str = CITY, m: int = CITY_M[0], families: dict | None = None, best: dict | None = None) -> dict:
    """A city's answer in numbers with m links (README's line and the chapter's two cities; the chapter derives each).

    Parameters
    ----------
    city : str
        The stored city's name.
    m : int
        The links, one of ``CITY_M``.
    families : dict or None
        {σ of ``CITY_CLOCK_PRIORS_S``: ``clock_families(m, σ, city=city)``} where the caller has them (the chapter);
        None: computed here.
    best : dict or None
        {(σ, quantile 0.5 or 0.9): ``intervals.best_comparison`` of those families} where the caller has them; None:
        computed here.

    Returns
    -------
    dict
        "n_ue" the traced UEs, "hear_pct" {k: the share of UEs that hear k or more BSs (%) for k = 3, 4, 6},
        "hear_m_pct" the share that hear m, "n_trials", "clock_half_m" the DPE's clock window with the clock model's
        prior (m), "dpe_p90_m" and "otdoa_p90_m" the honest DPE's and first-path OTDoA's 90 % errors with it (m),
        "best_otdoa" the best OTDoA receiver at the 90 % point with the same clock window and "best_otdoa_p90_m" its
        90 % error, "diff_p90" the best DPE − best OTDoA at the 90 % point as (value, lo, hi) m, "best" {(σ of
        ``CITY_CLOCK_PRIORS_S``, None: no prior; quantile 0.5 or 0.9): ``intervals.BestComparison``}, "verdicts" {σ:
        (verdict at 50 %, at 90 %)}, "los_trial_pct" the share of the trials' links in LoS (%), "excess_trial_ns" the
        median first-path excess delay on the trials' NLoS links (the first path within ``FIRST_PATH_THRESHOLD_DB``
        of the strongest, ns), "umi_median_ns" TR 38.901's UMi median (ns), "scattering_coefficient" and
        "refraction", the tracer's settings (``city_trace.CitySpec``).
    """
    e = city_fig10(m, "otdoa", city=city)
    traced = city_paths.load_city(city)
    n_heard = heard_per_ue(traced, m)
    res = engine.run(e)
    fam = {p: clock_families(m, p, city=city) for p in CITY_CLOCK_PRIORS_S} if families is None else families
    if best is None:
        best = {(p, q): intervals.best_comparison(*fam[p], q) for p in CITY_CLOCK_PRIORS_S for q in (0.5, 0.9)}
    b = best[(CITY_CLOCK_PRIORS_S[0], 0.9)]
    links = link_populations(traced, e, res)["trial"]
    return {"n_ue": traced.n_ue, "hear_pct": {k: 100 * float(np.mean(n_heard >= k)) for k in (3, 4, 6)},
            "hear_m_pct": 100 * float(np.mean(n_heard >= m)), "n_trials": e.run.n_trials,
            "clock_half_m": e.receiver_search().bias_half_width_m,
            "dpe_p90_m": float(np.quantile(res.error_m[:, 0, 0], 0.9)),
            "otdoa_p90_m": float(np.quantile(res.otdoa_error_m[:, 0, 0, 0], 0.9)), "best_otdoa": b.best_b,
            "best_otdoa_p90_m": float(np.quantile(fam[CITY_CLOCK_PRIORS_S[0]][1][b.best_b], 0.9)),
            "diff_p90": (b.difference.value, b.difference.lo, b.difference.hi), "best": best,
            "verdicts": {p: (best[(p, 0.5)].verdict(), best[(p, 0.9)].verdict()) for p in CITY_CLOCK_PRIORS_S},
            "los_trial_pct": 100 * float(np.mean(traced.los[links])),
            "excess_trial_ns": 1e9 * float(np.median(traced.first_excess_s(FIRST_PATH_THRESHOLD_DB)[links & ~traced.los])),
            "umi_median_ns": 1e9 * propagation.TR38901_EXCESS_DELAY[propagation.NLOS_EXCESS_ROW].median_s,
            "scattering_coefficient": float(traced.spec["scattering_coefficient"]),
            "refraction": bool(traced.spec["refraction"])}
