"""A ray-traced city (Sionna RT): the scene, the base stations and UEs placed outdoors, and the traced paths of every
link, kept compact for the results store (``dataset``).

Needs ``sionna-rt`` (pinned in environment.txt) and, for Dr.Jit's CPU backend, LLVM ≥ 16: Debian's ``libllvm19``
(``ray_tracer.llvm_library``).  Only ``make reproduce`` traces the whole city (``trace_city``); ``make test`` re-traces a sample of
links against the stored ones (``dataset.verify_links``).

Units: metres (the scene's frame: x east, y north, z up, the ground at z = 0), seconds, dB, dBm.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import math
import sys
import textwrap
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..common import _checks
from .ray_tracer import llvm_library, solve_paths

#: the city scenes of Sionna RT this module knows
SCENES = ("munich", "etoile", "florence", "san_francisco")
#: carriers a city is traced at, Hz: 3GPP's FR1 and FR2 (410 MHz to 52.6 GHz), where the ITU materials Sionna RT
#: loads are defined (ITU-R P.2040: 1 to 100 GHz, some from 1 MHz)
MIN_FC_HZ, MAX_FC_HZ = 0.41e9, 52.6e9
#: the largest ``clearance_m``, metres: half a street of 10 m each side of a point
MAX_CLEARANCE_M = 10.0
#: ``outdoor_points`` gives up after this many rounds of 4n draws with fewer than n outdoor points (an outdoor share
#: of the region below 1 / (4 · 50) = 0.5 %: a clearance no point of the region meets, or a region without streets)
MAX_DRAW_ROUNDS = 50


@dataclass(frozen=True)
class CitySpec:
    """What is traced: the scene, the deployment in it and the solver's settings.

    Attributes
    ----------
    scene : str
        A Sionna RT city scene (``SCENES``), or the path of a Mitsuba XML scene file of one's own (``scene_file``).
    side_m : float
        Side of the square region, metres: the paper's 227,360 m² (476.8 m).
    n_bs : int
        Base stations in the region: the paper's 26 (114 per km²); ``place_bs`` places them, unless ``trace_city`` is
        given their positions.
    bs_height_m, ue_height_m : float
        Heights above the ground, metres: the paper's 10 m (UMi) and 2 m.
    n_ue : int
        Outdoor UE positions traced.
    power_dbm : float
        Every BS's transmit power, dBm (the paper's 24 dBm).
    fc_hz, bandwidth_hz : float
        Carrier and bandwidth, Hz (3 GHz, 100 MHz).
    max_depth : int
        Most interactions per path (specular reflections and diffractions).
    samples_per_src : int
        Rays shot per transmitter.
    diffraction : bool
        Whether paths diffracted on wedges are traced.
    edge_diffraction : bool
        Sionna RT's diffraction on free edges (a flag apart from wedge diffraction).
    diffuse_reflection : bool
        Whether diffuse reflection (scattering off rough walls) is traced.
    scattering_coefficient : float
        S in [0, 1], set on every material of the scene (Sionna RT loads them with S = 0, where diffuse reflection adds
        nothing); > 0 exactly when ``diffuse_reflection``.  No material of the scene comes with a measured S.
    refraction : bool
        Whether transmission through walls is traced.
    n_paths : int
        Paths kept per link (``compact_links``): the first to arrive and the strongest others.
    clearance_m : float
        A position is outdoors when the ground is open at it and at this distance north, south, east and west.
    seed : int
        Seed of the placements and of the path solver.
    """

    scene: str = "munich"
    side_m: float = math.sqrt(227_360.0)
    n_bs: int = 26
    bs_height_m: float = 10.0
    ue_height_m: float = 2.0
    n_ue: int = 5000
    power_dbm: float = 24.0
    fc_hz: float = 3e9
    bandwidth_hz: float = 100e6
    max_depth: int = 3
    samples_per_src: int = 100_000
    diffraction: bool = True
    edge_diffraction: bool = False
    diffuse_reflection: bool = True
    scattering_coefficient: float = 0.3
    refraction: bool = False
    n_paths: int = 16
    clearance_m: float = 1.0
    seed: int = 20261205

    def __post_init__(self):
        _checks.plain_fields(self)  # booleans True or False, ints given as floats (9.0) the same settings as 9
        if not (isinstance(self.scene, str) and (self.scene in SCENES or self.scene.lower().endswith(".xml"))):
            raise ValueError(f"scene must be one of {', '.join(SCENES)} (Sionna RT's cities) or a Mitsuba XML scene "
                             f"file (.xml), got {self.scene!r}")
        _checks.in_range("side_m", self.side_m, 50.0, 2000.0, "m")
        _checks.integer("n_bs", self.n_bs, 3, 200)
        _checks.in_range("bs_height_m", self.bs_height_m, 1.5, 150.0, "m")
        _checks.in_range("ue_height_m", self.ue_height_m, 0.5, 10.0, "m")
        _checks.integer("n_ue", self.n_ue, 1, 100_000)
        _checks.integer("max_depth", self.max_depth, 0, 6)
        _checks.integer("n_paths", self.n_paths, 1, 256)
        _checks.integer("samples_per_src", self.samples_per_src, 1000, 10_000_000)
        _checks.in_range("scattering_coefficient", self.scattering_coefficient, 0.0, 1.0, "")
        _checks.in_range("power_dbm", self.power_dbm, -30.0, 60.0, "dBm")
        _checks.in_range("fc_hz", self.fc_hz, MIN_FC_HZ, MAX_FC_HZ, "Hz")
        _checks.in_range("bandwidth_hz", self.bandwidth_hz, 1e6, 2e9, "Hz")
        _checks.in_range("clearance_m", self.clearance_m, 0.0, MAX_CLEARANCE_M, "m")
        _checks.integer("seed", self.seed, 0, 2**32 - 1)
        if (self.scattering_coefficient > 0) != self.diffuse_reflection:
            raise ValueError("scattering_coefficient must be > 0 exactly when diffuse_reflection is on (with S = 0 "
                             f"diffuse reflection adds nothing), got {self.scattering_coefficient!r} and "
                             f"{self.diffuse_reflection!r}")

    def to_dict(self) -> dict:
        """The settings as plain JSON values.

        Returns
        -------
        dict
        """
        return asdict(self)


#: the functions whose code makes a traced city (``code_digest``)
TRACING_CODE = ("CitySpec", "scene_file", "load_scene", "ground_open", "outdoors", "densest_square", "outdoor_points",
                "place_bs", "place_ues", "ues_per_call", "solve_paths", "bs_groups", "trace_links", "compact_links",
                "layout", "trace_city")


#: today's tracing code → the earlier one it traces as (``code_digest``s): a stored city that records the earlier is
#: current.  8f0bae123f4e7ea6 (``scene_file``: a scene file of one's own; ``trace_city`` given a region and BSs)
#: traces Sionna RT's scenes at its own placements as be5f1ddeef7b47d5 did: the stored city's links of 8 UEs traced
#: again agreed with the stored ones (``dataset.verify_links``), as ``make test`` checks on a sample at every run
#: ff41ab9fa78779a4 (``layout``: ``trace_city``'s placements as a function of their own, the same calls in the same
#: order, so that ``trace_chunks`` places a city as ``trace_city`` does) traces as 8f0bae123f4e7ea6 did;
#: be3769bb50c7cb45 (``bs_groups``: more than 26 BSs traced in calls of 26; ``ues_per_call`` read by the digest) traces
#: a city of at most 26 BSs in the same calls as ff41ab9fa78779a4 did.  Every one of these holds for a city whose BSs
#: are one group of ``bs_groups`` (``dataset.is_current`` asks that of today's digest's)
SAME_TRACE_AS = {"8f0bae123f4e7ea6": "be5f1ddeef7b47d5", "ff41ab9fa78779a4": "be5f1ddeef7b47d5",
                 "be3769bb50c7cb45": "be5f1ddeef7b47d5"}


@lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 (16 hex digits) of the code of ``TRACING_CODE``: the tracing code a stored city records.

    Read once per process: the code this process traces with, even where its files are edited while it runs (the
    source is read from the files, and a long trace read an edited ``ray_tracer.py`` for its later cities' cache keys).

    Each function's or class's syntax tree less what cannot change a traced city: docstrings, the checks that refuse
    settings (``__post_init__``, and each ``if …: raise …``: code that only stops a trace never changes one that ran
    to its end), and the folder each ``from … import`` names (the same names, moved between modules, trace the same
    city).  Any other change of the code changes the digest.

    Returns
    -------
    str
    """
    h = hashlib.sha256()
    for name in TRACING_CODE:
        h.update(tracing_code(textwrap.dedent(inspect.getsource(getattr(sys.modules[__name__], name)))).encode())
    return h.hexdigest()[:16]


def tracing_code(source: str) -> str:
    """What ``code_digest`` reads of Python ``source``: its syntax tree less docstrings, refusals and import folders.

    Parameters
    ----------
    source : str
        A function's or class's code.

    Returns
    -------
    str
        The reduced tree (``ast.dump``).
    """
    return ast.dump(_TracingCode().visit(ast.parse(source)))


class _TracingCode(ast.NodeTransformer):
    """``code_digest``'s reading of a syntax tree: docstrings, refusals and import folders taken out."""

    def generic_visit(self, node):
        node = super().generic_visit(node)
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.ClassDef, ast.FunctionDef)) and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
        return node

    def visit_FunctionDef(self, node):
        return None if node.name == "__post_init__" else self.generic_visit(node)

    def visit_If(self, node):
        refusal = not node.orelse and all(isinstance(s, ast.Raise) for s in node.body)
        return None if refusal else self.generic_visit(node)

    def visit_ImportFrom(self, node):
        node.module, node.level = None, 0
        return node


def scene_file(scene: str) -> str:
    """The Mitsuba XML file of ``scene``: Sionna RT's for one of ``SCENES``, else ``scene`` itself, a file of one's own.

    Parameters
    ----------
    scene : str
        ``CitySpec.scene``.

    Returns
    -------
    str
        The file's path.

    Raises
    ------
    ValueError
        When a scene file of one's own does not exist.
    """
    if scene in SCENES:
        import sionna.rt as rt  # (Sionna RT: loaded only to trace)

        return getattr(rt.scene, scene)
    if not Path(scene).is_file():
        raise ValueError(f"scene {scene}: no such Mitsuba XML scene file")
    return str(Path(scene).resolve())


def load_scene(spec: CitySpec):
    """The Sionna RT scene of ``spec``: its ITU materials with the scattering coefficient ``spec.scattering_coefficient``,
    isotropic vertically polarised antennas at both ends.

    Parameters
    ----------
    spec : CitySpec
        The scene's name, carrier, bandwidth and scattering coefficient.

    Returns
    -------
    sionna.rt.Scene
    """
    llvm_library()
    import sionna.rt as rt  # (Sionna RT: loaded only to trace)

    scene = rt.load_scene(scene_file(spec.scene), merge_shapes=True)
    scene.frequency = spec.fc_hz
    scene.bandwidth = spec.bandwidth_hz
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="iso", polarization="V")
    for material in scene.radio_materials.values():
        material.scattering_coefficient = spec.scattering_coefficient
    return scene


def ground_open(scene, xy) -> np.ndarray:
    """Whether a ray cast straight down at each point meets the ground (z < 0.5 m), not a roof.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    xy : float (P, 2)
        Points, metres.

    Returns
    -------
    bool (P,)
    """
    import mitsuba as mi  # (Sionna RT: loaded only to trace)

    xy = np.asarray(xy, dtype=np.float32)
    top = np.full(len(xy), 1000.0, np.float32)
    ray = mi.Ray3f(mi.Point3f(mi.Float(xy[:, 0]), mi.Float(xy[:, 1]), mi.Float(top)), mi.Vector3f(0, 0, -1))
    hit = scene.mi_scene.ray_intersect(ray)
    return np.asarray(hit.is_valid()) & (np.asarray(hit.p.z) < 0.5)


def outdoors(scene, xy, clearance_m: float) -> np.ndarray:
    """Whether each point is outdoors: the ground open at it and ``clearance_m`` north, south, east and west of it.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    xy : float (P, 2)
        Points, metres.
    clearance_m : float
        Distance to the nearest wall at least, metres (tested in the four directions).

    Returns
    -------
    bool (P,)
    """
    xy = np.asarray(xy, dtype=float)
    ok = ground_open(scene, xy)
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        ok &= ground_open(scene, xy + clearance_m * np.array([dx, dy]))
    return ok


def densest_square(scene, side_m: float, step_m: float = 5.0) -> tuple[float, float, float, float]:
    """The square of side ``side_m`` inside the scene with the largest share of built ground (a dense urban area).

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    side_m : float
        The square's side, metres.
    step_m : float
        The grid on which the share is counted and the square placed, metres.

    Returns
    -------
    tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    """
    bb = scene.mi_scene.bbox()
    xs = np.arange(bb.min.x, bb.max.x, step_m)
    ys = np.arange(bb.min.y, bb.max.y, step_m)
    gx, gy = np.meshgrid(xs, ys)
    built = ~ground_open(scene, np.column_stack([gx.ravel(), gy.ravel()])).reshape(gx.shape)
    n = int(round(side_m / step_m))
    c = np.pad(np.cumsum(np.cumsum(built, 0), 1), ((1, 0), (1, 0)))
    share = c[n:, n:] - c[:-n, n:] - c[n:, :-n] + c[:-n, :-n]
    i, j = np.unravel_index(np.argmax(share), share.shape)
    return float(xs[j]), float(ys[i]), float(xs[j] + side_m), float(ys[i] + side_m)


def outdoor_points(scene, region, n: int, clearance_m: float, rng: np.random.Generator) -> np.ndarray:
    """n points uniform over the outdoor part of ``region`` (rejection sampling).

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    n : int
        Points wanted.
    clearance_m : float
        ``outdoors``'s clearance, metres.
    rng : numpy.random.Generator
        The draws.

    Returns
    -------
    float (n, 2)
        The points, metres, in the order drawn.
    """
    x0, y0, x1, y1 = region
    kept = []
    while sum(len(k) for k in kept) < n:
        if len(kept) == MAX_DRAW_ROUNDS:
            raise ValueError(f"clearance_m {clearance_m} m: {sum(len(k) for k in kept)} of {MAX_DRAW_ROUNDS * 4 * n} "
                             f"points drawn in the region {tuple(round(v, 1) for v in region)} are outdoors, fewer "
                             f"than the {n} wanted; a smaller clearance_m or another region (side_m, scene)")
        p = np.column_stack([rng.uniform(x0, x1, 4 * n), rng.uniform(y0, y1, 4 * n)])
        kept.append(p[outdoors(scene, p, clearance_m)])
    return np.concatenate(kept)[:n]


def place_bs(scene, region, spec: CitySpec) -> np.ndarray:
    """``spec.n_bs`` BS sites spread evenly over the outdoor part of the region, as a planned network would be.

    Farthest-point sampling over 4000 outdoor candidates, then 20 Lloyd (k-means) iterations, each centre moved to the
    nearest candidate: a street-level site (a pole or a façade) ``clearance_m`` from the walls at least.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    spec : CitySpec
        The number of BSs, their height, the clearance and the seed.

    Returns
    -------
    float (B, 3)
        The BS positions, metres.
    """
    rng = np.random.default_rng([spec.seed, 1])
    cand = outdoor_points(scene, region, 4000, spec.clearance_m, rng)
    centre = np.array([(region[0] + region[2]) / 2, (region[1] + region[3]) / 2])
    pick = [int(np.argmin(np.linalg.norm(cand - centre, axis=1)))]
    dist = np.linalg.norm(cand - cand[pick[0]], axis=1)
    while len(pick) < spec.n_bs:
        pick.append(int(np.argmax(dist)))
        dist = np.minimum(dist, np.linalg.norm(cand - cand[pick[-1]], axis=1))
    sites = cand[pick]
    for _ in range(20):
        owner = np.argmin(np.linalg.norm(cand[:, None] - sites[None], axis=2), axis=1)
        means = np.stack([cand[owner == b].mean(axis=0) if np.any(owner == b) else sites[b]
                          for b in range(spec.n_bs)])
        sites = cand[np.argmin(np.linalg.norm(cand[:, None] - means[None], axis=2), axis=0)]
    return np.column_stack([sites, np.full(spec.n_bs, spec.bs_height_m)])


def place_ues(scene, region, spec: CitySpec) -> np.ndarray:
    """``spec.n_ue`` UE positions uniform over the outdoor part of the region at the UE height.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    spec : CitySpec
        The number of UEs, their height, the clearance and the seed.

    Returns
    -------
    float (U, 3)
        The UE positions, metres.
    """
    xy = outdoor_points(scene, region, spec.n_ue, spec.clearance_m, np.random.default_rng([spec.seed, 2]))
    return np.column_stack([xy, np.full(spec.n_ue, spec.ue_height_m)])


def ues_per_call(spec: CitySpec) -> int:
    """UEs per call of the solver: 250, or 50 where diffuse reflection is traced (its paths fill the memory: 50 UEs at
    S = 0.3 took 15 GB, 200 more than this machine's 23 GB).  A UE's paths do not depend on the UEs traced beside it
    (``solve_paths``' table of chains is sized per UE; ``tests/city/test_city.py`` traces a few UEs alone and compares).

    Parameters
    ----------
    spec : CitySpec

    Returns
    -------
    int
    """
    return 50 if spec.diffuse_reflection else 250


def bs_groups(n_bs: int, per_call: int = 26) -> list[range]:
    """The BSs of each call of the solver: consecutive groups of ``per_call`` (one group for the paper's 26).

    A call's memory grows with its BSs (rays are launched per source): 26 BSs × 50 UEs with diffuse reflection took
    15 GB, and 104 BSs were killed for memory on a 23 GB machine at 50 UEs a call and at 12.

    A link's paths depend on the BSs traced beside it (the solver's rays are drawn per call: the same 12 UEs of 8 BSs
    traced in one call and in two calls of 4 gave 10 of 26 shared links other paths, up to 6.6 dB apart, with diffuse
    reflection, 1 of 12 without), so the groups are part of what is traced.

    Parameters
    ----------
    n_bs : int
        The BSs, B.
    per_call : int
        BSs per call (part of the tracing code: ``code_digest`` reads its default).

    Returns
    -------
    list of range
        Indices into the BSs, in order, covering 0 … B − 1.
    """
    if isinstance(per_call, bool) or not isinstance(per_call, int) or per_call < 1:
        raise ValueError(f"per_call must be an integer ≥ 1 (BSs per call of the solver), got {per_call!r}")
    return [range(b, min(b + per_call, n_bs)) for b in range(0, n_bs, per_call)]


def trace_links(scene, bs_xyz, ue_xyz, spec: CitySpec, batch: int | None = None, progress=None) -> dict:
    """Trace every BS → UE link (``solve_paths``) and keep each link's ``spec.n_paths`` paths (``compact_links``).

    UEs are traced ``batch`` at a time (``ues_per_call(spec)`` when None), each batch with the BSs of each of
    ``bs_groups`` in a call of its own.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene (``load_scene``).
    bs_xyz : float (B, 3)
        Transmitters, metres.
    ue_xyz : float (U, 3)
        Receivers, metres.
    spec : CitySpec
        The solver's settings and the paths kept.
    batch : int or None
        UEs per call of the solver.
    progress : callable or None
        Called with the number of UEs done after each batch.

    Returns
    -------
    dict
        ``compact_links``'s arrays over the links that have a path, their UE and BS indices in "link_ue", "link_bs",
        in order of UE, then BS.
    """
    parts, batch = [], batch or ues_per_call(spec)
    bs_xyz = np.asarray(bs_xyz, float)
    for u0 in range(0, len(ue_xyz), batch):
        ues = np.asarray(ue_xyz[u0:u0 + batch], float)
        for group in bs_groups(len(bs_xyz)):
            paths = solve_paths(scene, bs_xyz[group.start:group.stop], ues, spec)
            a, tau = paths.cir(normalize_delays=False, out_type="numpy")  # (U, 1, B, 1, P, 1), (U, B, P)
            a = a[:, 0, :, 0, :, 0]
            valid = np.asarray(paths.valid.numpy()) & (np.abs(a) > 0)
            direct = np.all(np.asarray(paths.interactions.numpy()) == 0, axis=0) & valid  # no interaction: LoS
            part = compact_links(a, tau, valid, direct, bs_xyz[group.start:group.stop], ues, spec.n_paths)
            part["link_ue"], part["link_bs"] = part["link_ue"] + u0, part["link_bs"] + group.start
            parts.append(part)
        if progress is not None:
            progress(len(ues))
    links = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    order = np.lexsort((links["link_bs"], links["link_ue"]))  # (the order of one call where one group)
    return {k: v[order] for k, v in links.items()}


def compact_links(a, tau, valid, direct, bs_xyz, ue_xyz, n_paths: int) -> dict:
    """Each link's first path and its strongest others, n_paths in all, in order of arrival.

    Parameters
    ----------
    a : complex (U, B, P)
        Path gains (amplitude, antenna patterns included).
    tau : float (U, B, P)
        Absolute path delays, seconds.
    valid, direct : bool (U, B, P)
        Whether a path exists; whether it is the LoS path.
    bs_xyz : float (B, 3)
        BS positions, metres.
    ue_xyz : float (U, 3)
        UE positions, metres.
    n_paths : int
        K, the paths kept per link.

    Returns
    -------
    dict
        Over the L links with a path: "link_ue", "link_bs" int (L,); "excess_s" float32 (L, K), each path's delay
        after the straight line's d/c, seconds; "gains" complex64 (L, K), zero where a link has fewer than K paths;
        "n_paths" int16 (L,); "los" bool (L,), whether the LoS path exists; "power_db" float32 (L,), the link's
        traced path gain Σ|a|² over all its paths, dB; "kept_db" float32 (L,), the power of the K kept over it, dB.
    """
    from ..phy.nr import C  # (here, as the stored city's tracing code was written: ``code_digest`` reads it)

    pw = np.where(valid, np.abs(a) ** 2, 0.0)
    has = valid.any(axis=-1)
    lu, lb = np.nonzero(has)
    d = np.linalg.norm(np.asarray(ue_xyz, float)[lu] - np.asarray(bs_xyz, float)[lb], axis=1)
    t = np.where(valid[lu, lb], tau[lu, lb].astype(float), np.inf)  # (L, P)
    p = pw[lu, lb]
    first = np.argmin(t, axis=1)
    rank = np.where(np.isfinite(t), p, -1.0)
    rank[np.arange(len(lu)), first] = np.inf  # the first path is always kept
    k = min(n_paths, t.shape[1])
    keep = np.argsort(-rank, axis=1, kind="stable")[:, :k]
    keep = np.take_along_axis(keep, np.argsort(np.take_along_axis(t, keep, 1), axis=1, kind="stable"), 1)
    tk, ok = np.take_along_axis(t, keep, 1), np.take_along_axis(valid[lu, lb], keep, 1)
    excess = np.where(ok, tk - d[:, None] / C, 0.0)
    gains = np.where(ok, np.take_along_axis(a[lu, lb], keep, 1), 0.0)
    total = p.sum(axis=1)
    out = {"link_ue": lu.astype(np.int32), "link_bs": lb.astype(np.int16),
           "excess_s": np.pad(excess, ((0, 0), (0, n_paths - k))).astype(np.float32),
           "gains": np.pad(gains, ((0, 0), (0, n_paths - k))).astype(np.complex64),
           "n_paths": valid[lu, lb].sum(axis=1).astype(np.int16), "los": direct[lu, lb].any(axis=1),
           "power_db": (10 * np.log10(total)).astype(np.float32),
           "kept_db": (10 * np.log10((np.abs(gains) ** 2).sum(axis=1) / total)).astype(np.float32)}
    return out


def layout(spec: CitySpec, region=None, bs_xyz=None):
    """The scene of ``spec`` with its region, BSs and UEs: everything ``trace_city`` traces the links of.

    Parameters
    ----------
    spec : CitySpec
        What to trace.
    region : tuple of 4 float or None
        (x_min, y_min, x_max, y_max), metres, in the scene's frame; None: the densest square of side ``spec.side_m``
        (``densest_square``).
    bs_xyz : float (B, 3) or None
        The BSs, metres (B = ``spec.n_bs``); None: placed as a planned network would be (``place_bs``).

    Returns
    -------
    scene : sionna.rt.Scene
    region : tuple of 4 float
        Metres.
    bs : float (B, 3)
        Metres.
    ue : float (U, 3)
        Metres.
    """
    if bs_xyz is not None and np.shape(bs_xyz) != (spec.n_bs, 3):
        raise ValueError(f"bs_xyz must be ({spec.n_bs}, 3) metres (spec.n_bs BSs), got shape {np.shape(bs_xyz)}")
    scene = load_scene(spec)
    region = densest_square(scene, spec.side_m) if region is None else tuple(float(v) for v in region)
    bs = place_bs(scene, region, spec) if bs_xyz is None else np.asarray(bs_xyz, dtype=float)
    return scene, region, bs, place_ues(scene, region, spec)


def trace_city(spec: CitySpec, progress: bool = True, region=None, bs_xyz=None) -> dict:
    """The whole city of ``spec``: its region, BS and UE placements and every link's kept paths, in this process on
    Dr.Jit's threads.

    ``dpe5g trace`` traces with ``trace_chunks.trace_city``: the same batches, each on one thread (the same bits at every
    run), cached as they are traced and run in chunks, here or on a Dask cluster.

    Parameters
    ----------
    spec : CitySpec
        What to trace.
    progress : bool
        Whether to show a progress bar over the UEs.
    region, bs_xyz
        As in ``layout``.

    Returns
    -------
    dict
        "region" float (4,) metres, "bs_xyz" (B, 3), "ue_xyz" (U, 3), and ``trace_links``'s arrays.
    """
    from tqdm import tqdm  # (here, as the stored city's tracing code was written: ``code_digest`` reads its imports)

    scene, region, bs, ue = layout(spec, region, bs_xyz)
    with tqdm(total=len(ue), desc=f"tracing {spec.scene}: {len(bs)} BSs", unit="UE", disable=not progress) as bar:
        links = trace_links(scene, bs, ue, spec, progress=bar.update)
    return {"region": np.asarray(region), "bs_xyz": bs, "ue_xyz": ue} | links
