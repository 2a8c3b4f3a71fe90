"""The ray tracer's settings tested: a subset of the city's UEs traced again with what the stored city leaves out.

The stored city (``city_trace.CitySpec``, ``ray_tracer.solve_paths``) traces the line of sight, specular reflections
and wedge diffraction, up to 3 interactions, 10⁵ rays per BS; diffuse reflection, refraction and edge diffraction are
off, and Sionna RT loads the scene's ITU materials with a scattering coefficient S of 0, so that diffuse reflection
adds nothing until S is set.  ``VARIANTS`` names each setting tried (``SolverVariant``); ``trace_variant`` traces the
first ``SUBSET_UES`` UEs of the stored city, with every BS, under one of them (the first variant as stored, so that
the subset is compared with itself traced the same way); ``save_variant`` and ``load_variant`` keep each in the
results store beside the city, in its format (``city_paths``).  ``make reproduce`` traces them (``dpe5g trace``).
No material of the scene comes with a measured S: the values swept are ours.
Units: metres, seconds.
"""

from __future__ import annotations

import io
import json
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from . import _checks, city_paths
from ._io import atomic_write, jsonable
from .chunk_cache import arrays_digest

#: the UEs of the subset: the stored city's first SUBSET_UES, every BS
SUBSET_UES = 200
#: UEs per call of the solver where diffuse reflection is traced (``batch_ues``)
DIFFUSE_BATCH_UES = 50


@dataclass(frozen=True)
class SolverVariant:
    """One setting of Sionna RT's path solver beside the stored city's.

    Attributes
    ----------
    max_depth : int
        Most interactions per path (the stored city's 3).
    samples_per_src : int
        Rays shot per BS (the stored city's 10⁵).
    diffuse_reflection : bool
        Diffuse reflection (scattering off rough walls) traced.
    scattering_coefficient : float
        S in [0, 1] set on every material of the scene (Sionna RT's default 0); needs diffuse_reflection.
    refraction : bool
        Transmission through walls traced.
    edge_diffraction : bool
        Sionna RT's diffraction on free edges (a flag apart from wedge diffraction).
    """

    max_depth: int = 3
    samples_per_src: int = 100_000
    diffuse_reflection: bool = False
    scattering_coefficient: float = 0.0
    refraction: bool = False
    edge_diffraction: bool = False

    def __post_init__(self):
        _checks.integer("max_depth", self.max_depth, 1, 6)
        _checks.integer("samples_per_src", self.samples_per_src, 1000, 10_000_000)
        _checks.in_range("scattering_coefficient", self.scattering_coefficient, 0.0, 1.0, "")
        if (self.scattering_coefficient > 0) != self.diffuse_reflection:
            raise ValueError("scattering_coefficient must be > 0 exactly when diffuse_reflection is on (with S = 0 "
                             f"diffuse reflection adds nothing), got {self.scattering_coefficient!r} and "
                             f"{self.diffuse_reflection!r}")


#: the settings tried, by name (a file name in the store) and label
VARIANTS = {
    "stored": ("as stored", SolverVariant()),
    "depth5": ("5 interactions", SolverVariant(max_depth=5)),
    "rays1e6": ("10⁶ rays per BS", SolverVariant(samples_per_src=1_000_000)),
    "refraction": ("refraction", SolverVariant(refraction=True)),
    "edge": ("edge diffraction", SolverVariant(edge_diffraction=True)),
    "diffuse01": ("diffuse, S = 0.1", SolverVariant(diffuse_reflection=True, scattering_coefficient=0.1)),
    "diffuse03": ("diffuse, S = 0.3", SolverVariant(diffuse_reflection=True, scattering_coefficient=0.3)),
    "diffuse05": ("diffuse, S = 0.5", SolverVariant(diffuse_reflection=True, scattering_coefficient=0.5)),
    "all03": ("all of them, S = 0.3", SolverVariant(max_depth=5, diffuse_reflection=True, scattering_coefficient=0.3,
                                                     refraction=True, edge_diffraction=True)),
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


def batch_ues(key: str) -> int:
    """UEs per call of the solver for ``VARIANTS[key]``.

    ``SUBSET_UES`` (one call, as the stored city traces batches of 250), or ``DIFFUSE_BATCH_UES`` with diffuse
    reflection, whose paths fill the memory (200 UEs at S = 0.3 needed more than this machine's 23 GB).

    Parameters
    ----------
    key : str
        A key of ``VARIANTS``.

    Returns
    -------
    int
    """
    return DIFFUSE_BATCH_UES if VARIANTS[key][1].diffuse_reflection else SUBSET_UES


def trace_variant(city: city_paths.TracedCity, key: str, n_ue: int = SUBSET_UES) -> dict:
    """The first n_ue UEs of ``city`` traced again with every BS under ``VARIANTS[key]``, ``batch_ues(key)`` UEs per
    call of the solver.

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
    import mitsuba as mi
    import sionna.rt as rt

    from . import city_trace

    variant = VARIANTS[key][1]
    spec = replace(city_trace.CitySpec(**city.spec), max_depth=variant.max_depth,
                   samples_per_src=variant.samples_per_src)
    scene = city_trace.load_scene(spec)
    for mat in scene.radio_materials.values():
        mat.scattering_coefficient = variant.scattering_coefficient
    ues = np.asarray(city.ue_xyz[:_checks.integer("n_ue", n_ue, 1, city.n_ue)], float)
    for b, p in enumerate(city.bs_xyz):
        scene.add(rt.Transmitter(f"bs{b}", position=mi.Point3f(*map(float, p)), power_dbm=spec.power_dbm))
    parts, seconds, step = [], 0.0, batch_ues(key)
    for u0 in range(0, len(ues), step):
        for name in list(scene.receivers):
            scene.remove(name)
        for u, p in enumerate(ues[u0:u0 + step]):
            scene.add(rt.Receiver(f"ue{u}", position=mi.Point3f(*map(float, p))))
        t0 = time.perf_counter()
        part = _solve(scene, spec, variant, city.bs_xyz, ues[u0:u0 + step])
        seconds += time.perf_counter() - t0
        part["link_ue"] = part["link_ue"] + u0
        parts.append(part)
    links = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return {"region": city.region, "bs_xyz": city.bs_xyz, "ue_xyz": ues, **links, "seconds": seconds}


def _solve(scene, spec, variant: SolverVariant, bs_xyz, ues) -> dict:
    """One call of the path solver on the scene's receivers, its paths kept as ``city_trace.compact_links`` keeps
    them, its table of specular chains sized as ``ray_tracer.solve_paths`` sizes it."""
    import sionna.rt as rt
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator

    from . import city_trace
    from .ray_tracer import CHAIN_SLOTS_PER_UE

    default = SBCandidateGenerator.MIN_SPEC_COUNT_SIZE
    SBCandidateGenerator.MIN_SPEC_COUNT_SIZE = max(default, CHAIN_SLOTS_PER_UE * len(ues))
    try:
        paths = rt.PathSolver()(scene, max_depth=spec.max_depth, samples_per_src=spec.samples_per_src, los=True,
                                specular_reflection=True, diffuse_reflection=variant.diffuse_reflection,
                                refraction=variant.refraction, diffraction=spec.diffraction,
                                edge_diffraction=variant.edge_diffraction, seed=spec.seed)
        a, tau = paths.cir(normalize_delays=False, out_type="numpy")  # (U, 1, B, 1, P, 1), (U, B, P)
    finally:
        SBCandidateGenerator.MIN_SPEC_COUNT_SIZE = default
    a = a[:, 0, :, 0, :, 0]
    valid = np.asarray(paths.valid.numpy()) & (np.abs(a) > 0)
    direct = np.all(np.asarray(paths.interactions.numpy()) == 0, axis=0) & valid  # no interaction: the LoS path
    return city_trace.compact_links(a, tau, valid, direct, bs_xyz, ues, spec.n_paths)


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
    arrays = {k: np.asarray(traced[k]) for k in city_paths.ARRAYS}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    spec = {**city.spec, "max_depth": VARIANTS[key][1].max_depth, "samples_per_src": VARIANTS[key][1].samples_per_src}
    city_sum = json.loads(city_paths.city_file(city.name).with_suffix(".json").read_text())["checksum"]
    meta = {"name": name, "spec": spec, "variant": asdict(VARIANTS[key][1]), "label": VARIANTS[key][0],
            "ues_per_call": batch_ues(key),
            "checksum": arrays_digest(arrays), "city_checksum": city_sum, "provenance": {**provenance, "seconds": float(traced["seconds"])}}
    path = city_paths.city_file(name)
    atomic_write(path, buf.getvalue())
    atomic_write(path.with_suffix(".json"), json.dumps(jsonable(meta), indent=1).encode())
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
        Its files exist, and its record names this variant and the city's checksum.
    """
    path = city_paths.city_file(variant_name(city.name, key))
    try:
        meta = json.loads(path.with_suffix(".json").read_text())
    except (OSError, ValueError):
        return False
    city_sum = json.loads(city_paths.city_file(city.name).with_suffix(".json").read_text())["checksum"]
    return path.exists() and meta.get("variant") == asdict(VARIANTS[key][1]) and meta.get("city_checksum") == city_sum


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
    return sub, json.loads(city_paths.city_file(name).with_suffix(".json").read_text())


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
    from . import city_trace

    scene = city_trace.load_scene(city_trace.CitySpec(**city.spec))
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
    from . import ray_tracer, store

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
