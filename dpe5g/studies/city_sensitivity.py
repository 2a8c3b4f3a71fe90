"""The ray tracer's settings tested: a subset of the city's UEs traced again under each setting of the path solver.

The city was first traced (``SPECULAR``) with the line of sight, specular reflections and wedge diffraction, up to 3
interactions, 10⁵ rays per BS; diffuse reflection, refraction and edge diffraction off, and Sionna RT loads the scene's
ITU materials with a scattering coefficient S of 0, so that diffuse reflection adds nothing until S is set.
``VARIANTS`` names each setting tried, as ``city_trace.CitySpec`` fields (``variant_spec``); ``trace_variant`` traces
the first ``SUBSET_UES`` UEs of the stored city, with every BS, under one of them (the variant with the city's own
settings is the city's first UEs traced again, so that the subset is compared with itself); ``save_variant`` and
``load_variant`` keep each in the results store beside the city, in its format (``city_paths``).  ``make reproduce``
traces them (``dpe5g trace``).  No material of the scene comes with a measured S: the values swept are ours.
Units: metres, seconds.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace

import numpy as np

from ..common import _checks
from ..common._io import arrays_digest, atomic_write
from ..city import dataset as city_paths, ray_tracer, trace as city_trace
from ..simulation import store
from . import city as city_study

#: the UEs of the subset: the stored city's first SUBSET_UES, every BS
SUBSET_UES = 200
#: the solver's settings of the city as first traced (LoS, specular reflections, wedge diffraction, 3 interactions, 10⁵
#: rays per BS): every variant is these with some changed (``city_trace.CitySpec``'s fields)
SPECULAR = {"max_depth": 3, "samples_per_src": 100_000, "diffuse_reflection": False, "scattering_coefficient": 0.0,
            "refraction": False, "edge_diffraction": False}


def _diffuse(s: float) -> dict:
    return {**SPECULAR, "diffuse_reflection": True, "scattering_coefficient": s}


#: the settings tried, by name (a file name in the store): their label and their solver settings
VARIANTS = {
    "specular": ("specular only (the city as first traced)", SPECULAR),
    "depth5": ("5 interactions", {**SPECULAR, "max_depth": 5}),
    "rays1e6": ("10⁶ rays per BS", {**SPECULAR, "samples_per_src": 1_000_000}),
    "refraction": ("refraction", {**SPECULAR, "refraction": True}),
    "edge": ("edge diffraction", {**SPECULAR, "edge_diffraction": True}),
    "diffuse01": ("diffuse, S = 0.1", _diffuse(0.1)),
    "diffuse03": ("diffuse, S = 0.3 (the city's settings)", _diffuse(0.3)),
    "diffuse05": ("diffuse, S = 0.5", _diffuse(0.5)),
    "all03": ("all of them, S = 0.3", {**_diffuse(0.3), "max_depth": 5, "refraction": True, "edge_diffraction": True}),
}


def variant_name(city: str, key: str) -> str:
    """The store's name of ``city``'s subset traced under ``VARIANTS[key]``.

    Parameters
    ----------
    city : str
        The stored city's name.
    key : str
        A key of ``VARIANTS``.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        An unknown key.
    """
    if key not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)}, got {key!r}")
    return f"{city}-settings-{key}"


def variant_spec(city: city_paths.TracedCity, key: str):
    """``city``'s ``city_trace.CitySpec`` (scene, deployment, seed) with the solver settings of ``VARIANTS[key]``.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    key : str
        A key of ``VARIANTS``.

    Returns
    -------
    city_trace.CitySpec
    """

    variant_name(city.name, key)
    return replace(city_trace.CitySpec(**city.spec), **VARIANTS[key][1])


def positions_digest(city: city_paths.TracedCity) -> str:
    """Digest of the subset's positions: ``city``'s BSs and first ``SUBSET_UES`` UEs (what a subset is traced at).

    Parameters
    ----------
    city : city_paths.TracedCity

    Returns
    -------
    str
    """
    return arrays_digest({"bs_xyz": np.asarray(city.bs_xyz), "ue_xyz": np.asarray(city.ue_xyz[:SUBSET_UES])})


def trace_variant(city: city_paths.TracedCity, key: str, n_ue: int = SUBSET_UES) -> dict:
    """The first n_ue UEs of ``city`` traced again with every BS under ``VARIANTS[key]`` (``city_trace.trace_links``).

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city: its scene, carrier, BSs, UEs, seed and kept paths per link (``city.spec``).
    key : str
        A key of ``VARIANTS``.
    n_ue : int
        UEs traced.

    Returns
    -------
    dict
        ``city_trace.trace_city``'s arrays for the subset (its region, BSs, the n_ue UEs and their links), and
        "seconds", the solver's time.
    """

    spec = variant_spec(city, key)
    ues = np.asarray(city.ue_xyz[:_checks.integer("n_ue", n_ue, 1, city.n_ue)], float)
    t0 = time.perf_counter()
    links = city_trace.trace_links(city_trace.load_scene(spec), city.bs_xyz, ues, spec)
    return {"region": city.region, "bs_xyz": city.bs_xyz, "ue_xyz": ues, **links, "seconds": time.perf_counter() - t0,
            "ues_per_call": city_trace.ues_per_call(spec)}


def save_variant(city: city_paths.TracedCity, key: str, traced: dict, provenance: dict) -> str:
    """Write a traced subset to the store beside ``city`` (``city_paths.city_file`` of ``variant_name``).

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city it was traced from.
    key : str
        Its key of ``VARIANTS``.
    traced : dict
        ``trace_variant``'s arrays.
    provenance : dict
        What traced it: commit, library versions.

    Returns
    -------
    str
        The subset's name in the store.
    """
    name = variant_name(city.name, key)
    city_paths.save_city(name, traced, variant_spec(city, key).to_dict(),
                         {**provenance, "seconds": float(traced["seconds"]), "ues_per_call": traced["ues_per_call"]},
                         extra={"label": VARIANTS[key][0], "positions": positions_digest(city)})
    return name


def is_current(city: city_paths.TracedCity, key: str) -> bool:
    """Whether the store holds ``city``'s subset traced under ``VARIANTS[key]`` from today's stored city.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    key : str
        A key of ``VARIANTS``.

    Returns
    -------
    bool
        Its files (paths, record, deployment) whole (``city_paths.check_city``), and its record names this variant's
        settings (``variant_spec``)
        and the positions of today's city (``positions_digest``): a city traced again with other solver settings at the
        same positions leaves them current.
    """
    name = variant_name(city.name, key)
    if city_paths.check_city(name) is not None:  # a damaged or missing part: traced again
        return False
    meta = city_paths.read_record(name)
    return meta.get("spec") == variant_spec(city, key).to_dict() and meta.get("positions") == positions_digest(city)


def load_variant(city: str, key: str) -> tuple[city_paths.TracedCity, dict]:
    """A traced subset from the store, its checksum checked (``city_paths.load_city``), and its record.

    Parameters
    ----------
    city : str
        The stored city's name.
    key : str
        A key of ``VARIANTS``.

    Returns
    -------
    city_paths.TracedCity, dict
        The subset, and its .json ("variant", "label", "provenance" with the solver's "seconds").
    """
    name = variant_name(city, key)
    sub = city_paths.load_city(name)
    return sub, city_paths.read_record(name)


def materials_file(city: str):
    """The store's record of the radio materials of ``city``'s scene as Sionna RT loads them (``save_materials``).

    Parameters
    ----------
    city : str
        The stored city's name.

    Returns
    -------
    pathlib.Path
    """
    return city_paths.city_file(f"{city}-settings-materials").with_suffix(".json")


def save_materials(city: city_paths.TracedCity) -> dict:
    """Record each radio material of ``city``'s scene as loaded: its ITU type, slab thickness (m) and scattering
    coefficient, the properties that decide what refraction and diffuse reflection add.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.

    Returns
    -------
    dict
        {material: {"itu_type", "thickness_m", "scattering_coefficient"}}, also written to ``materials_file``.
    """

    as_loaded = replace(city_trace.CitySpec(**city.spec), diffuse_reflection=False, scattering_coefficient=0.0)
    scene = city_trace.load_scene(as_loaded)  # S = 0 is what Sionna RT loads
    out = {name: {"itu_type": str(m.itu_type), "thickness_m": float(np.asarray(m.thickness).ravel()[0]),
                  "scattering_coefficient": float(np.asarray(m.scattering_coefficient).ravel()[0])}
           for name, m in scene.radio_materials.items()}
    atomic_write(materials_file(city.name), json.dumps(out, indent=1).encode())
    return out


def load_materials(city: str) -> dict:
    """``save_materials``' record.

    Parameters
    ----------
    city : str
        The stored city's name.

    Returns
    -------
    dict
    """
    return json.loads(materials_file(city).read_text())


def trace_stale(city: city_paths.TracedCity, force: bool = False):
    """Trace and store every subset of ``VARIANTS`` that is not current (``is_current``), or all with ``force``.

    Parameters
    ----------
    city : city_paths.TracedCity
        The stored city.
    force : bool
        Trace every variant again.

    Yields
    ------
    str
        One line per variant: traced (links, seconds) or current.
    """

    if force or not materials_file(city.name).exists():
        yield f"{materials_file(city.name).name}: {len(save_materials(city))} materials recorded"
    for key, (label, _) in VARIANTS.items():
        if not force and is_current(city, key):
            yield f"{variant_name(city.name, key)} ({label}) is current"
            continue
        traced = trace_variant(city, key)
        name = save_variant(city, key, traced, {"commit": store.git_commit(),
                                                "libraries": ray_tracer.library_versions()})
        yield (f"{name} ({label}): {len(traced['link_ue'])} links of {SUBSET_UES} UEs traced in "
               f"{traced['seconds']:.0f} s")


def settings_experiment(key: str, city: str = "munich"):
    """The city's honest DPE and OTDoA on ``city``'s subset traced under ``VARIANTS[key]``
    (``city_study.stored_city_fig10`` with ``city_study.CITY_M[0]`` links): every UE of the subset that hears that many
    BSs.

    Parameters
    ----------
    key : str
        A key of ``VARIANTS``.
    city : str
        The stored city's name.

    Returns
    -------
    Experiment
        "city-{subset}-m{M}-otdoa", its deployment the subset's (``deployment.builtin``).
    """
    return city_study.stored_city_fig10(variant_name(city, key), city_study.CITY_M[0])


def settings_families(key: str, city: str = "munich") -> tuple[dict, dict]:
    """The DPE and OTDoA families of ``settings_experiment(key)`` on its trials, with the same clock knowledge
    (``city_study.same_clock_families``).

    Parameters
    ----------
    key : str
        A key of ``VARIANTS``.
    city : str
        The stored city's name.

    Returns
    -------
    dpe, otdoa : dict
        {"naive DPE": errors (T,) m}; {"first-path OTDoA", "strongest-peak OTDoA", and the ToA fits of eq. (T1) in
        the DPE's windows: errors (T,) m}.
    """
    return city_study.same_clock_families(settings_experiment(key, city))


def all_experiments(city: str = "munich") -> list:
    """``settings_experiment`` of every variant: the store's entries of the tracer's settings.

    Parameters
    ----------
    city : str
        The stored city's name.

    Returns
    -------
    list of Experiment
    """
    return [settings_experiment(key, city) for key in VARIANTS]
