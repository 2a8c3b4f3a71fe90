"""The density sweep: the city's question at the paper's density of BSs and on denser networks (ours, beyond the paper).

The book's city has the paper's 26 BSs on its 476.8 m square (114 per km²).  ``FACTORS`` multiplies that: each network
is the book's ``city_trace.CitySpec`` (scene, square, solver settings, seed) with ``factor`` times the BSs, placed as a
planned network would be (``city_trace.place_bs``: the factor-1 network is the book's BSs), and the same ``DENSITY_UES``
UEs (``city_trace.place_ues`` depends on the seed, the square and their number, not on the BSs).  A network of more
than 26 BSs is traced in calls of 26 (``city_trace.bs_groups``).  ``dpe5g trace`` traces them into the results store
beside the city (``make reproduce``); on each, the city's honest DPE and every OTDoA receiver run on every UE that hears
``city_study.CITY_M[0]`` BSs, told the clock model's 5 ns and told nothing (``experiments``).
Units: BSs per km², metres, seconds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..city import dataset as city_paths, trace as city_trace
from ..simulation.experiment import Experiment
from . import city as city_study, intervals

#: the networks: these multiples of the paper's density (1: the paper's 114 BSs per km²)
FACTORS = (1, 2, 4)
#: UEs traced in each network, the same positions in all of them
DENSITY_UES = 500
#: the clock priors each network's DPE is told: the clock model's σ (s) and none (``city_study.clock_twin``)
DENSITY_CLOCK_PRIORS_S = (city_study.CITY_CLOCK_PRIORS_S[0], None)


def density_name(city: str, factor: int) -> str:
    """The store's name of ``city``'s network at ``factor`` times its density.

    Parameters
    ----------
    city : str
        The stored city's name.
    factor : int
        One of ``FACTORS``.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        A factor not in ``FACTORS``.
    """
    if isinstance(factor, bool) or not isinstance(factor, int) or factor not in FACTORS:
        raise ValueError(f"factor must be one of {', '.join(map(str, FACTORS))}, got {factor!r}")
    return f"{city}-density{factor}"


def density_spec(city: city_paths.TracedCity, factor: int) -> city_trace.CitySpec:
    """``city``'s ``CitySpec`` with ``factor`` times its BSs and ``DENSITY_UES`` UEs.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    factor : int
        One of ``FACTORS``.

    Returns
    -------
    city_trace.CitySpec
    """
    density_name(city.name, factor)
    return replace(city_trace.CitySpec(**city.spec), n_bs=factor * city.n_bs, n_ue=DENSITY_UES)


def is_current(city: city_paths.TracedCity, factor: int) -> bool:
    """Whether the store holds ``city``'s network at ``factor`` whole, traced with ``density_spec`` by today's tracing
    code (``city_paths.is_current``).

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    factor : int
        One of ``FACTORS``.

    Returns
    -------
    bool
    """
    return city_paths.is_current(density_name(city.name, factor), density_spec(city, factor).to_dict(),
                                 city_trace.code_digest())


def trace_stale(city: city_paths.TracedCity, tracer, provenance, force: bool = False):
    """Trace and store each network of ``FACTORS`` that is not current (``is_current``), or all with ``force``.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    tracer : callable
        ``tracer(spec)`` → a traced city's arrays (``dpe5g trace``: ``trace_chunks.trace_city`` here or on Dask).
    provenance : callable
        ``provenance(spec, start)`` → the record's provenance, ``start`` the ``time.perf_counter()`` before tracing.
    force : bool
        Trace every network again.

    Yields
    ------
    str
        One line per network: traced (links, seconds) or current.
    """
    for factor in FACTORS:
        name, spec = density_name(city.name, factor), density_spec(city, factor)
        if not force and is_current(city, factor):
            yield f"{name} ({spec.n_bs} BSs) is current"
            continue
        start = time.perf_counter()
        traced = tracer(spec)
        record = provenance(spec, start)
        city_paths.save_city(name, traced, spec.to_dict(), record, extra={"factor": factor})
        yield (f"{name}: {len(traced['link_ue'])} links of {spec.n_ue} UEs and {spec.n_bs} BSs traced in "
               f"{record['seconds']:.0f} s")


def experiments(factor: int, city: str = city_study.CITY) -> dict:
    """The city's honest DPE and OTDoA on the network at ``factor``: every UE that hears ``city_study.CITY_M[0]`` BSs
    (``city_study.stored_city_fig10``), the DPE told each clock prior of ``DENSITY_CLOCK_PRIORS_S``.

    Parameters
    ----------
    factor : int
        One of ``FACTORS``.
    city : str
        The stored city's name.

    Returns
    -------
    dict
        {prior (s, or None): Experiment}, on the same trials.
    """
    e = city_study.stored_city_fig10(density_name(city, factor), city_study.CITY_M[0])
    return {p: city_study.clock_twin(e, p) for p in DENSITY_CLOCK_PRIORS_S}


def all_experiments(city: str = city_study.CITY) -> list[Experiment]:
    """Every network's ``experiments``: the store's entries of the density sweep.

    Parameters
    ----------
    city : str
        The stored city's name.

    Returns
    -------
    list of Experiment
    """
    return [e for f in FACTORS for e in experiments(f, city).values()]


#: the points of the error distribution compared, as quantiles
QUANTILES = (0.5, 0.9)


@dataclass(frozen=True)
class DensityComparison:
    """DPE against OTDoA on one network with one clock prior, on the same trials (``comparison``).

    Attributes
    ----------
    n_trials : int
        Trials: the network's UEs that hear four BSs.
    dpe_m, otdoa_m : tuple of float
        The naive DPE's and first-path OTDoA's errors at ``QUANTILES``, metres.
    naive : tuple of intervals.Interval
        Naive DPE − first-path OTDoA at each of ``QUANTILES``, paired, metres.
    best : tuple of intervals.BestComparison
        The best DPE against the best OTDoA (the ToA fits given the DPE's window) at each of ``QUANTILES``.
    """

    n_trials: int
    dpe_m: tuple
    otdoa_m: tuple
    naive: tuple
    best: tuple


def comparison(factor: int, prior_s: float | None, city: str = city_study.CITY) -> DensityComparison:
    """The naive DPE against first-path OTDoA, and the best of each family, on the network at ``factor`` with the DPE
    told the clock to ``prior_s`` (a value of ``DENSITY_CLOCK_PRIORS_S``), from its stored experiment.

    Parameters
    ----------
    factor : int
        One of ``FACTORS``.
    prior_s : float or None
        Seconds, or None: no clock prior.
    city : str
        The stored city's name.

    Returns
    -------
    DensityComparison
    """
    if prior_s not in DENSITY_CLOCK_PRIORS_S:
        raise ValueError(f"prior_s must be one of {DENSITY_CLOCK_PRIORS_S}, got {prior_s!r}")
    dpe, otdoa = city_study.same_clock_families(experiments(factor, city)[prior_s])
    a, b = dpe["naive DPE"], otdoa["first-path OTDoA"]
    return DensityComparison(len(a), tuple(float(np.quantile(a, q)) for q in QUANTILES),
                             tuple(float(np.quantile(b, q)) for q in QUANTILES),
                             tuple(intervals.quantile_difference(a, b, q) for q in QUANTILES),
                             tuple(intervals.best_comparison(dpe, otdoa, q) for q in QUANTILES))
