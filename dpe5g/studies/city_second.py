"""The second city: the city chapter's question on another street pattern, Sionna RT's Étoile (ours, beyond the paper).

The book's city is one square of Munich's old centre: narrow, irregular streets between closed blocks.  Étoile (Paris,
around the Arc de Triomphe) is another street pattern: wide avenues radiating from a roundabout, on flat ground, with
buildings up to about 50 m; 60 % of its densest 476.8 m square is outdoors (``city_trace.outdoors``).  (San
Francisco's scene, the other candidate, lies on hills, its ground 0 to 171 m high, and ``city_trace.ground_open``
places UEs on flat ground only.)  The second city is the book's ``city_trace.CitySpec`` (the paper's square and 26 BSs,
114 per km², the solver's settings, the seed) in that scene with ``SECOND_UES`` UEs, fewer than the book city's
(``CitySpec.n_ue``): each brings about twice as many traced links, and the results store has a size budget.  ``dpe5g trace`` traces it into the store beside the city (``make
reproduce``), with its 3-D view; every experiment of the city chapter runs on it (``all_experiments``:
``city_study.all_experiments`` of ``SECOND_CITY``).  The solver-settings subsets and the density sweep stay Munich's.
"""

from __future__ import annotations

import time
from dataclasses import replace

from ..city import dataset as city_paths, trace as city_trace
from ..simulation.experiment import Experiment
from . import city as city_study

#: the second city's name in the store, and its Sionna RT scene
SECOND_CITY = "etoile"
#: its outdoor UEs traced
SECOND_UES = 800


def second_spec() -> city_trace.CitySpec:
    """The second city's ``CitySpec``: the book's, in the scene ``SECOND_CITY`` with ``SECOND_UES`` UEs.

    Returns
    -------
    city_trace.CitySpec
    """
    return replace(city_trace.CitySpec(), scene=SECOND_CITY, n_ue=SECOND_UES)


def is_current() -> bool:
    """Whether the store holds the second city whole, traced with ``second_spec`` by today's tracing code.

    Returns
    -------
    bool
    """
    return city_paths.is_current(SECOND_CITY, second_spec().to_dict(), city_trace.code_digest())


def trace_stale(tracer, provenance, force: bool = False):
    """Trace and store the second city unless it is current (``is_current``), or again with ``force``.

    Parameters
    ----------
    tracer : callable
        ``tracer(spec)`` → a traced city's arrays (``dpe5g trace``: ``trace_chunks.trace_city`` here or on Dask).
    provenance : callable
        ``provenance(spec, start)`` → the record's provenance, ``start`` the ``time.perf_counter()`` before tracing.
    force : bool
        Trace it again.

    Yields
    ------
    str
        One line: traced (links, seconds) or current.
    """
    spec = second_spec()
    if not force and is_current():
        yield f"{SECOND_CITY} ({spec.n_ue} UEs, {spec.n_bs} BSs) is current"
        return
    start = time.perf_counter()
    traced = tracer(spec)
    record = provenance(spec, start)
    city_paths.save_city(SECOND_CITY, traced, spec.to_dict(), record)
    yield (f"{SECOND_CITY}: {len(traced['link_ue'])} links of {spec.n_ue} UEs and {spec.n_bs} BSs traced in "
           f"{record['seconds']:.0f} s")


def all_experiments() -> list[Experiment]:
    """Every experiment of the city chapter on the second city (``city_study.all_experiments``): its store entries.

    Returns
    -------
    list of Experiment
    """
    return city_study.all_experiments(SECOND_CITY)
