"""A ray-traced city's links as a committed dataset of the results store (``figures/trials/cities``), typed
(``TracedCity``), checksummed, and re-traced in part by ``make test`` (``verify_links``).  ``dpe5g trace`` (``make reproduce``) traces
the city again only when its ``CitySpec`` or the tracing code changed (``is_current``).

Each link (UE u, BS b) that has at least one traced path keeps K of them (``city_trace.compact_links``): the first to
arrive and the strongest others, their delays after the straight line's d/c (float32, seconds) and their complex
amplitudes (complex64, the path gain with isotropic antennas).  A link with no path is absent: the UE does not hear
that BS.  ``save_city`` also writes the city's deployment (``deployment.BUILTIN``), whose file names the dataset's
checksum, so every experiment run on the city is keyed by the paths it read (``deployment.digest``).

Units: metres, seconds, dB.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common import _checks
from ..common._io import arrays_digest, jsonable, publish, published, read_npz
from ..common.errors import DamagedEntry
from ..common.locations import cities_dir
from ..phy import deployment
from ..phy.nr import C
from . import trace as city_trace

#: the store's subfolder of traced cities
CITY_FOLDER = "cities"
#: the arrays of a traced city, as stored
ARRAYS = ("region", "bs_xyz", "ue_xyz", "link_ue", "link_bs", "excess_s", "gains", "n_paths", "los", "power_db",
          "kept_db")
#: ``verify_links``'s tolerances against a re-trace.  A few UEs traced alone find the same first path of every link as
#: the whole city's trace (its excess delay and gain equal to float32 precision on 438 links of 64 UEs), but on some
#: links a path more or fewer (the solver's ray sampling), which moves the link's power by that path's share: up to
#: 2.83 dB (UE 648 → BS 18, 657 paths against 656 stored), while links with as many paths as stored agreed within
#: 1e-4 dB.  So: the first path's excess delay (s) and gain (dB) to these tolerances, the power (dB) of a link with as
#: many paths as stored to ``VERIFY_POWER_DB``, and the median power difference over every link compared (below
#: 1e-4 dB in each of 15 groups of 4 UEs) to ``VERIFY_MEDIAN_POWER_DB``, which a tracer that drifts on every link exceeds
VERIFY_EXCESS_S = 0.05e-9
VERIFY_GAIN_DB = 0.01
VERIFY_POWER_DB = 1.5
VERIFY_MEDIAN_POWER_DB = 0.1
#: links weaker than this path gain (dB) in both traces are not compared: 20 dB below the weakest link a UE hears
#: (``simulation.traced_draw.DETECTION_SNR_DB`` at 24 dBm is about −121 dB), where a path more or fewer decides whether one exists
VERIFY_FLOOR_DB = -140.0
#: the files of a traced city (``save_city``, one unit) and of its 3-D view (``save_view``, another): their suffixes
PARTS = (".npz", ".json", "_deployment.json")
VIEW_PARTS = ("_view.npz", "_view.json")


@dataclass(frozen=True, eq=False)
class TracedCity:
    """A traced city: its deployment and, over its L heard links, the kept paths.

    Attributes
    ----------
    name : str
        The city's name, also its deployment's (``deployment.BUILTIN``).
    spec : dict
        The ``city_trace.CitySpec`` it was traced with.
    region : float (4,)
        (x_min, y_min, x_max, y_max), metres.
    bs_xyz : float (B, 3)
        BS positions, metres.
    ue_xyz : float (U, 3)
        UE positions, metres.
    link_ue, link_bs : int (L,)
        Each heard link's UE and BS.
    excess_s : float32 (L, K)
        Each kept path's delay after d/c, seconds, in order of arrival (0 where a link has fewer than K paths).
    gains : complex64 (L, K)
        Each kept path's amplitude (0 where a link has fewer than K paths).
    n_paths : int (L,)
        The paths traced on each link (K or fewer kept).
    los : bool (L,)
        Whether the straight line is clear (the LoS path exists).
    power_db : float32 (L,)
        The link's path gain Σ|a|² over all its traced paths, dB.
    kept_db : float32 (L,)
        The power of the K kept paths over all, dB (≤ 0).
    """

    name: str
    spec: dict
    region: np.ndarray
    bs_xyz: np.ndarray
    ue_xyz: np.ndarray
    link_ue: np.ndarray
    link_bs: np.ndarray
    excess_s: np.ndarray
    gains: np.ndarray
    n_paths: np.ndarray
    los: np.ndarray
    power_db: np.ndarray
    kept_db: np.ndarray

    @property
    def n_ue(self) -> int:
        """U, the UE positions traced."""
        return len(self.ue_xyz)

    @property
    def n_bs(self) -> int:
        """B, the base stations."""
        return len(self.bs_xyz)

    def link_table(self) -> np.ndarray:
        """The link index of every (UE, BS), −1 where the UE hears no path from the BS.

        Returns
        -------
        int (U, B)
        """
        table = np.full((self.n_ue, self.n_bs), -1)
        table[self.link_ue, self.link_bs] = np.arange(len(self.link_ue))
        return table

    def heard(self) -> np.ndarray:
        """How many BSs each UE hears (at least one traced path).

        Returns
        -------
        int (U,)
        """
        return np.bincount(self.link_ue, minlength=self.n_ue)

    def first_excess_s(self, threshold_db: float | None = None) -> np.ndarray:
        """Each link's first-path excess delay: its first path's delay after d/c, seconds.

        The first path is the earliest traced path (the straight line's on a LoS link: 0), or, with ``threshold_db``,
        the earliest kept path whose power ``|a|²`` is within ``threshold_db`` of the link's strongest path's, as a
        first-path detector finds it (``studies.city.FIRST_PATH_THRESHOLD_DB``): never earlier than the earliest path,
        the strongest path at latest.

        Parameters
        ----------
        threshold_db : float or None
            The first path's power relative to the strongest path, dB, ≤ 0; None: the earliest path, however weak.

        Returns
        -------
        float (L,)

        Raises
        ------
        ValueError
            When threshold_db is above 0 dB or not a number.
        """
        if threshold_db is None:
            return self.excess_s[:, 0].astype(float)
        thr = _checks.in_range("threshold_db", threshold_db, -math.inf, 0.0, "dB")
        p = np.abs(self.gains.astype(np.complex128)) ** 2  # (L, K), 0 where a link has fewer than K paths
        above = p >= p.max(axis=1, keepdims=True) * 10.0 ** (thr / 10.0)
        above &= p > 0
        return self.excess_s[np.arange(len(p)), np.argmax(above, axis=1)].astype(float)


def city_folder(root: Path | None = None) -> Path:
    """The store's folder of traced cities.

    Parameters
    ----------
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    Path
    """
    return cities_dir() if root is None else root / CITY_FOLDER


def city_file(name: str, root: Path | None = None, part: str = ".npz") -> Path:
    """A file of the traced city ``name`` in the results store: its paths (``.npz``), its record (``.json``), its
    deployment file (``_deployment.json``) or its 3-D view (``_view.npz``, ``_view.json``), where a reader finds it
    (``_io.published``: the city's pending publication while ``save_city`` moves it into place).

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).
    part : str
        The file's suffix, one of ``PARTS`` and ``VIEW_PARTS``.

    Returns
    -------
    Path
    """
    unit = f"{name}_view" if _checks.name("name", name) and part.startswith("_view") else name
    return published(city_folder(root), unit, f"{name}{_checks.one_of('part', part, PARTS + VIEW_PARTS)}")


def read_record(name: str, root: Path | None = None) -> dict:
    """The record of the traced city ``name`` (its ``.json``: settings, checksums, provenance), as stored.

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    dict
    """
    return json.loads(city_file(name, root, ".json").read_text())


def check_city_name(param: str, name) -> str:
    """A traced city's name: a name (``_checks.name``), not ending in "_deployment" or "_view" (its deployment
    file's and its 3-D view's names end so).

    Parameters
    ----------
    param : str
        The parameter's name in the message.
    name : str
        The name.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        Naming ``param``.
    """
    if _checks.name(param, name).endswith(("_deployment", "_view")):
        raise ValueError(f"{param} must not end in _deployment or _view (the names of a city's other files), "
                         f"got {name!r}")
    return name


def save_city(name: str, traced: dict, spec: dict, provenance: dict, root: Path | None = None,
              extra: dict | None = None) -> Path:
    """Publish a traced city in the store, all its files or none (``_io.publish``): its arrays (``.npz``), its
    deployment file (``deployment_doc``) and its record (``.json``: name, settings, the arrays' checksum, provenance,
    ``extra``) sealed by ``record_checksum``.  Stopped at any point, the store holds the old city or the new one.

    Parameters
    ----------
    name : str
        The city's name.
    traced : dict
        ``city_trace.trace_city``'s arrays.
    spec : dict
        The ``CitySpec`` it was traced with.
    provenance : dict
        What traced it: commit, library versions, seconds.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).
    extra : dict or None
        More fields of the record (a subset's label and the positions it was traced at).

    Returns
    -------
    Path
        The ``.npz`` written.
    """
    check_city_name("name", name)
    arrays = {k: np.asarray(traced[k]) for k in ARRAYS}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    meta = jsonable({"name": name, "spec": spec, **(extra or {}), "checksum": arrays_digest(arrays),
                     "provenance": provenance})
    dep = deployment_doc(name, arrays, spec, meta["checksum"])
    meta["record_checksum"] = record_checksum(meta, dep)
    publish(city_folder(root), name, {f"{name}.npz": buf.getvalue(), f"{name}_deployment.json": dep,
                                      f"{name}.json": json.dumps(meta, indent=1).encode()})
    return city_file(name, root)


def record_checksum(meta: dict, deployment_bytes: bytes) -> str:
    """SHA-256 of a city's record (every field but this one, as sorted JSON) and of its deployment file's bytes: with
    the arrays' checksum inside the record, it covers the whole city.

    Parameters
    ----------
    meta : dict
        The record (its ``.json``).
    deployment_bytes : bytes
        Its deployment file.

    Returns
    -------
    str
        The hex digest.
    """
    record = json.dumps({k: v for k, v in meta.items() if k != "record_checksum"}, sort_keys=True)
    return hashlib.sha256(record.encode() + b"\0" + deployment_bytes).hexdigest()


def deployment_doc(name: str, arrays: dict, spec: dict, checksum: str) -> bytes:
    """The city's deployment file (``deployment_file``, beside its paths; ``deployment.builtin`` finds it): its BSs,
    region and UE height, and the paths' checksum.

    Parameters
    ----------
    name : str
        The city's name.
    arrays : dict
        The traced city's arrays ("region", "bs_xyz").
    spec : dict
        Its ``CitySpec`` (power, UE height, scene).
    checksum : str
        The dataset's checksum (``_io.arrays_digest``).

    Returns
    -------
    bytes
        The file's JSON.
    """
    x0, y0, x1, y1 = (float(v) for v in arrays["region"])
    doc = {"name": name,
           "description": (f"{len(arrays['bs_xyz'])} BSs placed outdoors in Sionna RT's '{spec['scene']}' scene, "
                           f"ray-traced paths in the results store ({CITY_FOLDER}/{name}.npz, checksum {checksum}); "
                           "made by dpe5g.city.dataset.save_city."),
           "region": {"x_min_m": x0, "y_min_m": y0, "x_max_m": x1, "y_max_m": y1},
           "ue_height_m": float(spec["ue_height_m"]),
           "base_stations": [{"id": f"C{b + 1:02d}", "x_m": float(p[0]), "y_m": float(p[1]), "height_m": float(p[2]),
                              "power_dbm": float(spec["power_dbm"])} for b, p in enumerate(arrays["bs_xyz"])]}
    return (json.dumps(doc, indent=1) + "\n").encode()


def view_file(name: str, root: Path | None = None) -> Path:
    """The ``.npz`` of the city's 3-D view (``save_view``) in the results store.

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    Path
    """
    return city_file(name, root, "_view.npz")


def save_view(name: str, view: dict, root: Path | None = None) -> Path:
    """Publish the city's 3-D view, both files or neither (``_io.publish``): the buildings' triangles and one UE's
    traced paths (``city_view.scene_triangles``, ``city_view.example_paths``), with the checksum of its arrays in a
    ``.json`` beside it.

    Parameters
    ----------
    name : str
        The city's name.
    view : dict
        "triangles", "ue" (the UE's index), "ue_bs" (its BSs) and ``city_view.example_paths``'s arrays.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    Path
    """
    arrays = {k: np.asarray(v) for k, v in view.items()}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    publish(city_folder(root), f"{_checks.name('name', name)}_view",
            {f"{name}_view.npz": buf.getvalue(),
             f"{name}_view.json": json.dumps({"checksum": arrays_digest(arrays)}).encode()})
    return view_file(name, root)


def load_view(name: str, root: Path | None = None) -> dict:
    """The city's 3-D view (``save_view``), its checksum checked.

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    dict

    Raises
    ------
    errors.DamagedEntry
        When it is missing or does not match its checksum.
    """
    path = view_file(name, root)
    try:
        arrays = read_npz(path)
        ok = arrays_digest(arrays) == json.loads(city_file(name, root, "_view.json").read_text())["checksum"]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DamagedEntry(path, f"cannot be read ({err}): dpe5g trace makes it again") from err
    if not ok:
        raise DamagedEntry(path, "its arrays do not match the checksum in its .json: dpe5g trace makes it again")
    return arrays


def is_current(name: str, spec: dict, code_digest: str, root: Path | None = None) -> bool:
    """Whether the stored city ``name`` is whole (``check_city``) and was traced with ``spec`` by the tracing code of
    ``code_digest``: a damaged or missing part makes it stale, so ``dpe5g trace`` traces it again.

    Parameters
    ----------
    name : str
        The city's name.
    spec : dict
        The ``CitySpec`` wanted.
    code_digest : str
        ``city_trace.code_digest()`` of today's tracing code (or the code it traces as, ``city_trace.SAME_TRACE_AS``).
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    bool
    """
    damage, meta, _ = _read_city(name, root)
    traced_by = meta.get("provenance", {}).get("code")
    one_group = len(city_trace.bs_groups(int(spec.get("n_bs", 0)))) <= 1  # (what SAME_TRACE_AS declares)
    same_code = traced_by == code_digest or (one_group and traced_by == city_trace.SAME_TRACE_AS.get(code_digest))
    return damage is None and meta.get("spec") == spec and same_code


def check_city(name: str, root: Path | None = None) -> str | None:
    """What is wrong with the stored city ``name``, in a few words, or None when it is whole: its ``.npz``, its
    ``.json`` and its deployment file present and readable; the arrays those of ``ARRAYS`` and equal to the recorded
    checksum; the record naming this city and a valid ``CitySpec``; the deployment file (``deployment_doc``) the
    arrays' base stations, in number and place, their power and the region; and the record and the deployment file
    equal to their ``record_checksum``.

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    str or None
    """
    return _read_city(name, root)[0]


def _read_city(name: str, root: Path | None) -> tuple[str | None, dict, dict]:
    """(``check_city``'s answer, the record, the arrays): one read of the files for the check and the load."""
    path, record, dep = (city_file(name, root, part) for part in PARTS)
    for part in (path, record, dep):
        if not part.is_file():
            return f"{part.name} is missing", {}, {}
    try:
        meta = json.loads(record.read_text())
        arrays = read_npz(path)
        dep_bytes = dep.read_bytes()
        doc = json.loads(dep_bytes)
    except (OSError, ValueError) as err:
        return f"cannot be read ({' '.join(str(err).split())[:160]})", {}, {}
    if not isinstance(meta, dict):
        return "its .json is not a city's record", {}, {}
    if set(arrays) != set(ARRAYS) or arrays_digest(arrays) != meta.get("checksum"):
        return "its arrays do not match the checksum in its .json", {}, {}
    damage = _record_damage(name, meta) or _deployment_damage(doc, arrays, meta["spec"])
    if damage is None and meta.get("record_checksum") != record_checksum(meta, dep_bytes):
        damage = "its .json or its deployment file is not what was traced (their checksum differs)"
    return damage, meta, arrays


def _record_damage(name: str, meta: dict) -> str | None:
    """What is wrong with a city's record (its ``.json``), or None."""
    if meta.get("name") != name or not isinstance(meta.get("spec"), dict):
        return "its .json does not name this city and its settings"
    try:
        city_trace.CitySpec(**meta["spec"])
    except (TypeError, ValueError) as err:
        return f"its .json holds settings that are not a CitySpec ({' '.join(str(err).split())[:160]})"
    return None


def _deployment_damage(doc, arrays: dict, spec: dict) -> str | None:
    """What is wrong with a city's deployment file against its arrays and settings, or None."""
    try:
        rows = doc["base_stations"]
        xyz = np.array([[r["x_m"], r["y_m"], r["height_m"]] for r in rows], dtype=np.float64)
        power = {float(r["power_dbm"]) for r in rows}
        region = [doc["region"][k] for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m")]
    except (KeyError, TypeError, ValueError):
        return "its deployment file is not a deployment"
    if xyz.shape != arrays["bs_xyz"].shape or not np.array_equal(xyz, arrays["bs_xyz"].astype(np.float64)):
        return "its deployment file's base stations are not the traced ones"
    if power != {float(spec["power_dbm"])} or region != [float(v) for v in arrays["region"]]:
        return "its deployment file's power or region is not the traced city's"
    return None


def deployment_file(name: str, root: Path | None = None) -> Path:
    """The deployment file of the traced city ``name`` (``deployment_doc``), beside its paths.

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    Path
    """
    return city_file(name, root, "_deployment.json")


def city_at(named: str) -> tuple[str, Path | None]:
    """The traced city a deployment names, as (name, store folder): a city of the store in use by its name, or the
    deployment file of a city in a folder of one's own, ``<folder>/cities/<name>_deployment.json`` (what
    ``dpe5g trace --out <folder>`` writes).

    Parameters
    ----------
    named : str
        ``Scenario.deployment`` of a traced channel.

    Returns
    -------
    name : str
    root : Path or None
        The store's folder (``load_city``'s root); None: the one in use.

    Raises
    ------
    ValueError
        When ``named`` is neither.
    """
    path = Path(named)
    if len(path.parts) == 1 and not named.endswith(".json"):
        return _checks.name("deployment", named), None
    if not path.name.endswith("_deployment.json") or path.parent.name != CITY_FOLDER:
        raise ValueError(f"deployment {named}: a traced city is a city of the results store by name, or its "
                         f"deployment file <folder>/{CITY_FOLDER}/<name>_deployment.json (dpe5g trace --out <folder>)")
    return _checks.name("deployment", path.name.removesuffix("_deployment.json")), path.parent.parent


def load_city(name: str, root: Path | None = None) -> TracedCity:
    """The traced city ``name`` from the store, checked whole (``check_city``).

    Parameters
    ----------
    name : str
        The city's name.
    root : Path or None
        The store's folder; None: the one in use (``locations.cities_dir``).

    Returns
    -------
    TracedCity

    Raises
    ------
    errors.DamagedEntry
        Naming what is damaged or missing, and ``dpe5g trace`` (``make reproduce``), which traces it again.
    """
    damage, meta, arrays = _read_city(name, root)
    if damage is not None:
        raise DamagedEntry(city_file(name, root), f"{damage}: dpe5g trace (make reproduce) traces the city again")
    return TracedCity(name=name, spec=meta["spec"], **{k: arrays[k] for k in ARRAYS})


def retrace_links(city: TracedCity, ues) -> dict:
    """Trace again the links of the UEs ``ues`` to every BS, as ``city_trace.trace_city`` traced them.

    Parameters
    ----------
    city : TracedCity
        The stored city.
    ues : int (n,)
        UE indices.

    Returns
    -------
    dict
        ``city_trace.compact_links``'s arrays, "link_ue" indexing into ``ues``.
    """

    spec = city_trace.CitySpec(**city.spec)
    scene = city_trace.load_scene(spec)
    return city_trace.trace_links(scene, city.bs_xyz, city.ue_xyz[np.asarray(ues)], spec, batch=len(ues))


def verify_links(city: TracedCity, ues) -> list[str]:
    """Re-trace the UEs ``ues`` (``retrace_links``) and compare with the stored links (``compare_links``).

    Parameters
    ----------
    city : TracedCity
        The stored city.
    ues : int (n,)
        UE indices.

    Returns
    -------
    list of str
        One line per difference; empty when the re-trace agrees.
    """
    return compare_links(city, ues, retrace_links(city, ues))


def compare_links(city: TracedCity, ues, new: dict) -> list[str]:
    """Compare a re-trace ``new`` of the UEs ``ues`` with the stored links above ``VERIFY_FLOOR_DB``: the same links,
    the same LoS states, the first path's excess delay within ``VERIFY_EXCESS_S`` and its gain within
    ``VERIFY_GAIN_DB``, the power within ``VERIFY_POWER_DB`` where as many paths were found as stored, and the median
    power difference within ``VERIFY_MEDIAN_POWER_DB``.

    Parameters
    ----------
    city : TracedCity
        The stored city.
    ues : int (n,)
        UE indices.
    new : dict
        ``retrace_links(city, ues)``.

    Returns
    -------
    list of str
        One line per difference; empty when the re-trace agrees.
    """
    ues = np.asarray(ues)
    table, out, dps = city.link_table(), [], []
    for i, u in enumerate(ues):
        mine = {int(b): j for j, b in zip(np.nonzero(new["link_ue"] == i)[0], new["link_bs"][new["link_ue"] == i])}
        for b in range(city.n_bs):
            k, j = table[u, b], mine.get(b)
            p_old = float(city.power_db[k]) if k >= 0 else -np.inf
            p_new = float(new["power_db"][j]) if j is not None else -np.inf
            if max(p_old, p_new) < VERIFY_FLOOR_DB:
                continue
            if k < 0 or j is None:
                out.append(f"UE {u}, BS {b}: path gain {p_new:.1f} dB traced today, {p_old:.1f} dB stored")
                continue
            dp, dx = abs(p_new - p_old), abs(float(new["excess_s"][j, 0]) - float(city.excess_s[k, 0]))
            dg = abs(_db(new["gains"][j, 0]) - _db(city.gains[k, 0]))
            dps.append(dp)
            same_paths = int(new["n_paths"][j]) == int(city.n_paths[k])
            if (bool(new["los"][j]) != bool(city.los[k]) or dx > VERIFY_EXCESS_S or dg > VERIFY_GAIN_DB
                    or (same_paths and dp > VERIFY_POWER_DB)):
                out.append(f"UE {u}, BS {b}: power {dp:.3g} dB, first-path delay {dx * 1e9:.3g} ns off, first-path "
                           f"gain {dg:.3g} dB off, LoS {bool(new['los'][j])} (stored {bool(city.los[k])})")
    if dps and np.median(dps) > VERIFY_MEDIAN_POWER_DB:
        out.append(f"UEs {ues.tolist()}: the links' median power difference is {np.median(dps):.3g} dB "
                   f"(> {VERIFY_MEDIAN_POWER_DB} dB)")
    return out


def _db(gain) -> float:
    """|gain|² in dB (−inf for 0)."""
    with np.errstate(divide="ignore"):
        return float(10 * np.log10(np.abs(gain) ** 2))


def path_gain_check(city: TracedCity) -> float:
    """The largest gap (dB) between a LoS link's first path and the free-space gain (λ/4πd)² of its straight line.

    The traced LoS path against Friis on a pure LoS link (``make test``'s check of the trace against the model).

    Parameters
    ----------
    city : TracedCity
        The stored city.

    Returns
    -------
    float
        The largest absolute difference, over the LoS links, between the first path's power (dB) and the free-space
        gain 20 lg(λ/4πd) (dB).
    """

    lam = C / float(city.spec["fc_hz"])
    los = np.nonzero(city.los)[0]
    d = np.linalg.norm(city.ue_xyz[city.link_ue[los]] - city.bs_xyz[city.link_bs[los]], axis=1)
    first = 10 * np.log10(np.abs(city.gains[los, 0].astype(complex)) ** 2)
    return float(np.max(np.abs(first - 20 * np.log10(lam / (4 * math.pi * d)))))
