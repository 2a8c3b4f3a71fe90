"""The deployment of Section III: base stations (position, height, power, ID), the region, buildings and streets,
read from a file and validated.

Units: metres (local ENU: x east, y north, z up, origin at the region's south-west corner), dBm.

The paper's 26 BS positions in Tsim Sha Tsui are not published.  ``tst()`` loads our layout with the paper's numbers
(26 BSs over a 227,360 m² square, BS height 10 m, 24 dBm) on a Tsim Sha Tsui-like street grid, made by
``scripts/make_layout.py``; ``load_deployment`` reads a user's deployment from JSON or CSV.  The propagation models
that act on a deployment (eq. (11), the path loss, the link budget, the clock bias) are in ``dpe5g.phy.propagation``.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common import _checks
from ..common._io import published
from ..common.locations import cities_dir
from .propagation import N_PRS_IDS, prs_plan

DATA_DIR = Path(__file__).resolve().parents[1] / "data"
TST_FILE = DATA_DIR / "tst_deployment.json"
#: the deployments packaged with dpe5g, by name (``builtin``): our Tsim Sha Tsui-like layout, and the rings of
#: the DPE chapter's studies (8 BSs on a 150 m circle, the UE in a 10 m or a 100 m square at its centre), made by
#: ``scripts/make_ring.py``; and the ray-traced city "munich", written beside its paths in the results store
#: (``city_paths.save_city``; ``builtin`` finds every traced dataset's there, its subsets' too)
BUILTIN = {"tst": TST_FILE, "ring": DATA_DIR / "ring_deployment.json",
           "ring-wide": DATA_DIR / "ring_wide_deployment.json"}

#: allowed ranges for a deployment's numbers
BS_HEIGHT_RANGE_M = (1.5, 150.0)  # TR 38.901 UMi: 10 m; the formulas need h_BS > h_E = 1 m
#: a BS transmit power in dBm: 10 dBm (a femtocell) to 60 dBm (1 kW, above any macro cell's 46-49 dBm); a value
#: below 10 is most likely in watts (24 dBm is 0.25 W)
POWER_RANGE_DBM = (10.0, 60.0)
MIN_BS = 3  # (x, y, c δt) has three unknowns
#: a BS's transmit power where its file gives none, dBm: the paper's 24 dBm (Section III).  The studies whose SNRs
#: come from the powers use it: the link budget (Fig. 10's set-up), PRS reuse's co-channel BSs, and which links of a
#: traced city are heard; reading a file without it says so (``Deployment.assumed``)
DEFAULT_POWER_DBM = 24.0
#: a CSV deployment's optional region columns (the same values on every row that gives them)
CSV_REGION = ("region_x_min_m", "region_y_min_m", "region_x_max_m", "region_y_max_m")
#: the region of a CSV deployment that gives none: the BSs' bounding box grown on each side by this share of its
#: larger side
CSV_REGION_PAD = 0.1
#: the largest deployment file read (bytes) and the most base stations and buildings it may hold: a city's
#: deployment is far below these; a larger file is most likely not a deployment
MAX_FILE_BYTES = 20_000_000
MAX_BS = N_PRS_IDS  # (without PRS reuse, each BS needs a PRS ID of its own)
MAX_BUILDINGS = 100_000
#: base stations must stand at least this far apart (m), and off one line by at least this much (RMS, m)
MIN_SPACING_M = 0.5


#: a deployment file's format, one paragraph, as ``dpe5g deployment --help`` prints it
FORMAT = " ".join(f"""
A deployment file is JSON or CSV; positions in metres in a local frame (x east, y north, z up, the ground at 0).
Each base station: x_m, y_m, height_m ({BS_HEIGHT_RANGE_M[0]:g} to {BS_HEIGHT_RANGE_M[1]:g} m), and optional id
(default BS01, BS02, ...) and power_dbm ({POWER_RANGE_DBM[0]:g} to {POWER_RANGE_DBM[1]:g} dBm; default
{DEFAULT_POWER_DBM:g} dBm, the paper's; used where the SNRs come from the powers: --snr-mode link-budget, --reuse).  At least {MIN_BS} and at most
{MAX_BS} BSs, {MIN_SPACING_M:g} m apart or more.  The region (x_min_m, y_min_m, x_max_m, y_max_m) is where the UE is
drawn and must hold every BS: JSON's "region" (required); a CSV's region_x_min_m, ... columns, or, without them, the
BSs' bounding box grown by {CSV_REGION_PAD:.0%} of its larger side on each side (a line says so).  JSON may also
give ue_height_m (default 2), ue_region, buildings, streets, anchor, name and description
(dpe5g/data/tst_deployment.json has them all).""".split())

#: a small deployment in each format, the same BSs and region (``dpe5g deployment --example json|csv``)
EXAMPLES = {
    "json": """\
{
 "name": "mine",
 "region": {"x_min_m": -50, "y_min_m": -50, "x_max_m": 350, "y_max_m": 350},
 "base_stations": [
  {"id": "A", "x_m": 0, "y_m": 0, "height_m": 10, "power_dbm": 24},
  {"id": "B", "x_m": 300, "y_m": 0, "height_m": 10, "power_dbm": 24},
  {"id": "C", "x_m": 0, "y_m": 300, "height_m": 10, "power_dbm": 24},
  {"id": "D", "x_m": 300, "y_m": 300, "height_m": 10, "power_dbm": 24},
  {"id": "E", "x_m": 150, "y_m": 150, "height_m": 25, "power_dbm": 30}
 ]
}
""",
    "csv": """\
id,x_m,y_m,height_m,power_dbm,region_x_min_m,region_y_min_m,region_x_max_m,region_y_max_m
A,0,0,10,24,-50,-50,350,350
B,300,0,10,24,,,,
C,0,300,10,24,,,,
D,300,300,10,24,,,,
E,150,150,25,30,,,,
""",
}


@dataclass(frozen=True, eq=False)
class Deployment:
    """Base stations over a rectangular region, with optional buildings and streets for the map and the 3-D scene.

    Attributes
    ----------
    name, description : str
        The deployment's name, and a free text about it.
    bs_ids : tuple of str (B,)
        The base stations' names.
    bs_xyz : float (B, 3)
        Base-station positions, metres.
    power_dbm : float (B,)
        Transmit power per BS, dBm.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    ue_height_m : float
        UE height, metres (2 m by default).
    buildings : float (K, 5)
        Rows (x_min, y_min, x_max, y_max, height), metres (may be empty).
    streets : tuple of dict
        Dicts (name, axis, centre_m, width_m), for drawing only.
    anchor_lat_deg, anchor_lon_deg : float or None
        WGS-84 position of the local origin, degrees, or None.
    ue_region : tuple of 4 float or None
        (x_min, y_min, x_max, y_max) metres, inside ``region``: where the UE is drawn, or None for the whole region
        (``ue_bounds``).
    assumed : tuple of str
        What reading the file filled in, one sentence each: a CSV's region inferred from its BSs, a power not given
        (``DEFAULT_POWER_DBM``).  The command line prints them.
    """

    name: str
    bs_ids: tuple[str, ...]
    bs_xyz: np.ndarray
    power_dbm: np.ndarray
    region: tuple[float, float, float, float]
    ue_height_m: float = 2.0
    buildings: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))
    streets: tuple = ()
    anchor_lat_deg: float | None = None
    anchor_lon_deg: float | None = None
    description: str = ""
    ue_region: tuple[float, float, float, float] | None = None
    assumed: tuple[str, ...] = ()

    @property
    def ue_bounds(self) -> tuple[float, float, float, float]:
        """The area the UE is drawn from, (x_min, y_min, x_max, y_max) in metres; ``ue_region``, else the region."""
        return self.region if self.ue_region is None else self.ue_region

    @property
    def n_bs(self) -> int:
        """Number of base stations B."""
        return len(self.bs_ids)

    @property
    def area_m2(self) -> float:
        """Area of the region, m²."""
        x0, y0, x1, y1 = self.region
        return (x1 - x0) * (y1 - y0)

    def check_ue(self, xy) -> np.ndarray:
        """Validate UE positions, finite and inside the UE's area (``ue_bounds``); return them as float64.

        Parameters
        ----------
        xy : float (..., 2)
            UE positions (x, y), metres.

        Returns
        -------
        numpy.ndarray float (..., 2)

        Raises
        ------
        ValueError
            A position not finite or outside the UE's area, or a shape other than (..., 2).
        """
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape[-1:] != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"UE position must be finite (..., 2) metres, got shape {xy.shape}")
        x0, y0, x1, y1 = self.ue_bounds
        inside = (xy[..., 0] >= x0) & (xy[..., 0] <= x1) & (xy[..., 1] >= y0) & (xy[..., 1] <= y1)
        if not np.all(inside):
            bad = xy[~inside].reshape(-1, 2)[0]
            raise ValueError(f"UE position must be inside the region x in [{x0:g}, {x1:g}] m, y in [{y0:g}, "
                             f"{y1:g}] m; got ({bad[0]:g}, {bad[1]:g})")
        return xy

    def prs_plan(self, reuse: int) -> tuple[np.ndarray, np.ndarray]:
        """The PRS resource and ID of every BS for frequency reuse ``reuse`` (``scenario.prs_plan``).

        Parameters
        ----------
        reuse : int
            As ``scenario.prs_plan``.

        Returns
        -------
        resource, prs_id : numpy.ndarray int (B,)
            As ``scenario.prs_plan``.
        """
        return prs_plan(self.bs_xyz, reuse)

    def nearest(self, ue_xy, m: int) -> np.ndarray:
        """Indices of the m BSs nearest to the UE in 2-D distance, nearest first.

        Parameters
        ----------
        ue_xy : float (..., 2)
            UE positions, metres, finite (anywhere: a UE outside the region has nearest BSs too).
        m : int
            Number of BSs, 1 to B.

        Returns
        -------
        numpy.ndarray int (..., m)

        Raises
        ------
        ValueError
            ``m`` out of range, or ``ue_xy`` not finite or not of shape (..., 2).
        """
        _checks.integer("m", m, 1, self.n_bs)
        _checks.values_in_range("ue_xy", ue_xy, -1e6, 1e6, "m")
        if np.shape(ue_xy)[-1:] != (2,):
            raise ValueError(f"ue_xy must have shape (..., 2), got {np.shape(ue_xy)}")
        d = np.linalg.norm(np.asarray(ue_xy)[..., None, :] - self.bs_xyz[:, :2], axis=-1)
        return np.argsort(d, axis=-1, kind="stable")[..., :m]


def _fail(source, msg):
    raise ValueError(f"deployment file {source}: {msg}")


def _number(source, where, key, value, lo, hi, unit, text: bool = False):
    """A finite number in [lo, hi]: a JSON number (not true/false), or with ``text`` (a CSV cell) its text."""
    if isinstance(value, bool) or (isinstance(value, str) and not text):
        _fail(source, f"{where}: {key} must be a number in [{lo:g}, {hi:g}] {unit}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        _fail(source, f"{where}: {key} must be a number in [{lo:g}, {hi:g}] {unit}, got {value!r}")
    if not math.isfinite(v) or not lo <= v <= hi:
        _fail(source, f"{where}: {key} must be in [{lo:g}, {hi:g}] {unit}, got {value!r}")
    return v


def _power(source, where, value, text: bool = False):
    """A BS transmit power in dBm within ``POWER_RANGE_DBM``; the error suggests watts for small positive values."""
    lo, hi = POWER_RANGE_DBM
    try:
        v = math.nan if isinstance(value, bool) or (isinstance(value, str) and not text) else float(value)
    except (TypeError, ValueError):
        v = math.nan
    if math.isfinite(v) and lo <= v <= hi:
        return v
    hint = ""
    if math.isfinite(v) and 0 < v < lo:
        hint = (f" — {v:g} dBm is {10 ** (v / 10):.3g} mW, not a base station; looks like watts? "
                f"{v:g} W is {10 * math.log10(v * 1e3):.1f} dBm")
    _fail(source, f"{where}: power_dbm must be in [{lo:g}, {hi:g}] dBm (a BS transmit power), got {value!r}{hint}")


def _base_stations(source, rows, text: bool = False):
    """Validate BS rows (dicts with id, x_m, y_m, height_m, optional power_dbm; ``text``: CSV cells) → ids, xyz,
    power (``DEFAULT_POWER_DBM`` where not given), and the sentence saying so (``Deployment.assumed``)."""
    if not isinstance(rows, list) or len(rows) < MIN_BS:
        n = len(rows) if isinstance(rows, list) else 0
        _fail(source, f"needs at least {MIN_BS} base stations (x, y and the clock bias are unknown), got {n}")
    if len(rows) > MAX_BS:
        _fail(source, f"holds {len(rows)} base stations; at most {MAX_BS} are read (one PRS ID each)")
    ids, seen, xyz, pw = [], set(), [], []
    for i, r in enumerate(rows):
        where = f"base station {i + 1}"
        if not isinstance(r, dict):
            _fail(source, f"{where} must be an object with id, x_m, y_m, height_m, power_dbm")
        missing = [k for k in ("x_m", "y_m", "height_m") if k not in r or r[k] in ("", None)]
        if missing:
            _fail(source, f"{where}: missing {', '.join(missing)}")
        bid = str(r.get("id") or f"BS{i + 1:02d}")
        if bid in seen:
            _fail(source, f"{where}: duplicate id {bid!r}")
        ids.append(bid)
        seen.add(bid)
        xyz.append([_number(source, where, "x_m", r["x_m"], -1e5, 1e5, "m", text),
                    _number(source, where, "y_m", r["y_m"], -1e5, 1e5, "m", text),
                    _number(source, where, "height_m", r["height_m"], *BS_HEIGHT_RANGE_M, "m", text)])
        given = r.get("power_dbm") not in ("", None)
        pw.append(_power(source, f"{where} ({bid})", r["power_dbm"], text) if given else math.nan)
    xyz = np.array(xyz)
    _check_geometry(source, tuple(ids), xyz[:, :2])
    pw = np.array(pw)
    unstated = [b for b, p in zip(ids, pw) if math.isnan(p)]
    assumed = () if not unstated else (
        f"power_dbm not given for {len(unstated)} of {len(ids)} BSs ({', '.join(unstated[:3])}"
        f"{', …' if len(unstated) > 3 else ''}): {DEFAULT_POWER_DBM:g} dBm (the paper's) where a study uses it",)
    return tuple(ids), xyz, np.where(np.isnan(pw), DEFAULT_POWER_DBM, pw), assumed


def nearest_neighbours(xy) -> tuple[np.ndarray, np.ndarray]:
    """Each BS's nearest other BS, by a k-d tree (B log B, not a B × B distance matrix).

    Parameters
    ----------
    xy : float (B, 2)
        BS positions, metres.

    Returns
    -------
    distance : numpy.ndarray float (B,)
        Distance to the nearest other BS, metres.
    index : numpy.ndarray int (B,)
        Its index.
    """
    from scipy.spatial import cKDTree  # (scipy.spatial: 0.9 s to import, only for the spacing check)

    d, j = cKDTree(xy).query(xy, k=2)
    other = j[:, 0] != np.arange(len(xy))  # two BSs at one place: the tree may list the other one first
    return np.where(other, d[:, 0], d[:, 1]), np.where(other, j[:, 0], j[:, 1])


def _check_geometry(source, ids, xy) -> None:
    """The BSs stand at least ``MIN_SPACING_M`` apart (nearest neighbours by a k-d tree: n log n, not n²) and not
    all on one line (their RMS distance from the best line at least ``MIN_SPACING_M``)."""
    d, j = nearest_neighbours(xy)
    i = int(np.argmin(d))
    if d[i] < MIN_SPACING_M:
        _fail(source, f"base stations {ids[i]} and {ids[j[i]]} are less than {MIN_SPACING_M:g} m apart")
    spread = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)[-1] / np.sqrt(len(xy))
    if spread < MIN_SPACING_M:
        _fail(source, f"the {len(ids)} base stations lie on one line (their RMS distance from it is {spread:.2g} m, "
                      f"under {MIN_SPACING_M:g} m): a position on either side of it gives the same ranges, so x, y "
                      f"cannot be resolved")


def load_deployment(path) -> Deployment:
    """Read a deployment from JSON (our schema, see ``dpe5g/data/tst_deployment.json``) or CSV (``FORMAT``,
    ``EXAMPLES``).

    * CSV: a header row with columns x_m, y_m, height_m and optional id, power_dbm and region columns
      (``CSV_REGION``, the same on every row that gives them), one BS per row; without region columns the region is
      the BSs' bounding box grown by ``CSV_REGION_PAD`` of its larger side on each side (``Deployment.assumed`` says
      so); the UE height 2 m.
    * JSON: ``{"base_stations": [{id, x_m, y_m, height_m, power_dbm}, ...], "region": {x_min_m, y_min_m, x_max_m,
      y_max_m}``, optional ``"ue_region"`` (the same keys, inside the region: where the UE is drawn),
      ``"ue_height_m"``, ``"buildings" [{x_min_m, y_min_m, x_max_m, y_max_m, height_m}]``, ``"streets" [{name, axis,
      centre_m, width_m}]``, ``"anchor" {lat_deg, lon_deg}``, ``"name"``, ``"description"}``; JSON numbers.
    * Either: a BS's id and power_dbm are optional (BS01, BS02, …; ``DEFAULT_POWER_DBM``).

    Parameters
    ----------
    path : str or pathlib.Path
        The file, ending in .json or .csv.

    Returns
    -------
    Deployment

    Raises
    ------
    ValueError
        A missing, unreadable or malformed file (over ``MAX_FILE_BYTES`` bytes, ``MAX_BS`` base stations or
        ``MAX_BUILDINGS`` buildings; BSs closer than ``MIN_SPACING_M`` or all on one line), naming the file, the
        entry and the allowed range, before any computation.
    """
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise ValueError(f"deployment file {src} does not exist")
    if not path.is_file():
        raise ValueError(f"deployment file {src} is not a file")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".json"):
        _fail(src, f"must end in .json or .csv, got {path.suffix!r}")
    try:
        size = path.stat().st_size
        if size > MAX_FILE_BYTES:
            _fail(src, f"is {size:,} bytes; a deployment file may hold at most {MAX_FILE_BYTES:,}")
        data = path.read_bytes()
    except OSError as e:
        _fail(src, f"cannot be read ({e.strerror or e})")
    return _from_csv(src, path.stem, data) if suffix == ".csv" else _from_json(src, path.stem, data)


def _from_csv(src: str, stem: str, data: bytes) -> Deployment:
    """A CSV deployment's rows (``load_deployment``)."""
    try:
        rows = list(csv.DictReader(io.StringIO(data.decode("utf-8-sig"), newline="")))
    except (UnicodeDecodeError, csv.Error) as e:
        _fail(src, f"cannot be read as CSV ({e})")
    for i, r in enumerate(rows):
        if None in r:
            _fail(src, f"row {i + 2} has more fields than the header")
    ids, xyz, pw, assumed = _base_stations(src, rows, text=True)
    region = _csv_region(src, rows)
    if region is None:
        lo, hi = xyz[:, :2].min(0), xyz[:, :2].max(0)
        pad = CSV_REGION_PAD * max(float(np.max(hi - lo)), 1.0)
        region = tuple(float(v) for v in (lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad))
        assumed += (f"region not given (columns {', '.join(CSV_REGION)}): the BSs' bounding box grown by "
                    f"{CSV_REGION_PAD:.0%} of its larger side ({pad:.1f} m) on each side, "
                    f"({', '.join(f'{v:.1f}' for v in region)}) m",)
    _inside(src, ids, xyz, region)
    return Deployment(stem, ids, xyz, pw, region, assumed=assumed)


def _csv_region(src: str, rows: list) -> tuple[float, float, float, float] | None:
    """A CSV deployment's region from its ``CSV_REGION`` columns (the same on every row that gives them), or None."""
    given = {tuple(_number(src, f"row {i + 2}", k, r.get(k), -1e5, 1e5, "m", True) for k in CSV_REGION)
             for i, r in enumerate(rows) if any(r.get(k) not in ("", None) for k in CSV_REGION)}
    if not given:
        return None
    if len(given) > 1:
        _fail(src, f"the region columns {', '.join(CSV_REGION)} differ between rows ({sorted(given)[:2]})")
    return _rectangle(src, "region", {k.removeprefix("region_"): v for k, v in zip(CSV_REGION, given.pop())})


def _inside(src: str, ids, xyz, region) -> None:
    """Every BS inside the region."""
    outside = [b for b, p in zip(ids, xyz) if not (region[0] <= p[0] <= region[2] and region[1] <= p[1] <= region[3])]
    if outside:
        _fail(src, f"base station {outside[0]} lies outside the region {region}")


def _from_json(src: str, stem: str, data: bytes) -> Deployment:
    """A JSON deployment's document (``load_deployment``)."""
    try:
        doc = json.loads(data)  # json.loads detects the UTF encoding; a bad one is a decode error
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        _fail(src, f"is not valid JSON ({e})")
    except RecursionError:
        _fail(src, "is nested too deeply to be a deployment")
    if not isinstance(doc, dict):
        _fail(src, "must hold a JSON object with base_stations and region")
    if "base_stations" not in doc:
        _fail(src, "missing base_stations" + (f" (it has {', '.join(map(repr, list(doc)[:8]))})" if doc else ""))
    ids, xyz, pw, assumed = _base_stations(src, doc["base_stations"])
    if not isinstance(doc.get("region"), dict):
        _fail(src, "needs a region {x_min_m, y_min_m, x_max_m, y_max_m}")
    region = _rectangle(src, "region", doc["region"])
    _inside(src, ids, xyz, region)
    ue_region = None
    if doc.get("ue_region") is not None:
        ue_region = _rectangle(src, "ue_region", doc["ue_region"])
        if any(ue_region[i] < region[i] for i in (0, 1)) or any(ue_region[i] > region[i] for i in (2, 3)):
            _fail(src, f"ue_region {ue_region} must lie inside the region {region}")
    ue_h = _number(src, "ue_height_m", "ue_height_m", doc.get("ue_height_m", 2.0), 1.0, 22.5, "m")
    lat, lon = _anchor(src, doc.get("anchor"))
    return Deployment(_text(src, "name", doc.get("name", stem)), ids, xyz, pw, region, ue_h,
                      _buildings(src, doc.get("buildings")), _streets(src, doc.get("streets")), lat, lon,
                      _text(src, "description", doc.get("description", "")), ue_region, assumed)


def _text(src, key, value) -> str:
    if not isinstance(value, str) or len(value) > 10_000:
        _fail(src, f"{key} must be a text of at most 10,000 characters, got {type(value).__name__}")
    return value


def _buildings(src, rows) -> np.ndarray:
    """The optional "buildings": a list of {x_min_m, y_min_m, x_max_m, y_max_m, height_m} → (K, 5) m."""
    if rows is None:
        return np.zeros((0, 5))
    if not isinstance(rows, list):
        _fail(src, f"buildings must be a list of objects, got {type(rows).__name__}")
    if len(rows) > MAX_BUILDINGS:
        _fail(src, f"holds {len(rows)} buildings; at most {MAX_BUILDINGS} are read")
    blds = []
    keys = ("x_min_m", "y_min_m", "x_max_m", "y_max_m", "height_m")
    for i, b in enumerate(rows):
        if not isinstance(b, dict) or any(k not in b for k in keys):
            _fail(src, f"building {i + 1} needs {', '.join(keys)}")
        row = [_number(src, f"building {i + 1}", k, b[k], -1e5, 1e5, "m") for k in keys]
        if row[2] <= row[0] or row[3] <= row[1] or row[4] <= 0:
            _fail(src, f"building {i + 1} must have x_max_m > x_min_m, y_max_m > y_min_m and height_m > 0")
        blds.append(row)
    return np.array(blds).reshape(-1, 5)


def _streets(src, rows) -> tuple:
    """The optional "streets" (for drawing): a list of {name, axis, centre_m, width_m}."""
    if rows is None:
        return ()
    if not isinstance(rows, list) or len(rows) > 10_000:
        _fail(src, "streets must be a list of at most 10,000 objects {name, axis, centre_m, width_m}")
    out = []
    for i, r in enumerate(rows):
        where = f"street {i + 1}"
        if not isinstance(r, dict) or any(k not in r for k in ("name", "axis", "centre_m", "width_m")):
            _fail(src, f"{where} needs name, axis, centre_m, width_m")
        if r["axis"] not in ("north-south", "east-west"):
            _fail(src, f"{where}: axis must be 'north-south' or 'east-west', got {r['axis']!r}")
        out.append({"name": _text(src, f"{where} name", r["name"]), "axis": r["axis"],
                    "centre_m": _number(src, where, "centre_m", r["centre_m"], -1e5, 1e5, "m"),
                    "width_m": _number(src, where, "width_m", r["width_m"], 0.1, 1000.0, "m")})
    return tuple(out)


def _anchor(src, anchor) -> tuple[float | None, float | None]:
    """The optional "anchor" {lat_deg, lon_deg}: the WGS-84 position of the local origin."""
    if anchor is None:
        return None, None
    if not isinstance(anchor, dict):
        _fail(src, f"anchor must be an object {{lat_deg, lon_deg}}, got {anchor!r:.40}")
    if anchor.get("lat_deg") is None and anchor.get("lon_deg") is None:
        return None, None
    return (_number(src, "anchor", "lat_deg", anchor.get("lat_deg"), -90, 90, "deg"),
            _number(src, "anchor", "lon_deg", anchor.get("lon_deg"), -180, 180, "deg"))


def _rectangle(src, key, reg) -> tuple[float, float, float, float]:
    """A JSON deployment's rectangle ``key`` ("region", "ue_region"): {x_min_m, y_min_m, x_max_m, y_max_m}, finite,
    at least 1 m wide and deep.  Returns (x_min, y_min, x_max, y_max) m."""
    if not isinstance(reg, dict):
        _fail(src, f"{key} must be an object {{x_min_m, y_min_m, x_max_m, y_max_m}}")
    box = tuple(_number(src, key, k, reg.get(k), -1e5, 1e5, "m") for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m"))
    if box[2] - box[0] < 1.0 or box[3] - box[1] < 1.0:
        _fail(src, f"{key} must have x_max_m > x_min_m and y_max_m > y_min_m (by at least 1 m), got {box}")
    return box


def builtin(name: str) -> Path | None:
    """The file of the packaged deployment ``name`` (``BUILTIN``), or of a traced city's ("munich" and its subsets, in
    ``locations.cities_dir``), or None.

    Parameters
    ----------
    name : str
        The packaged deployment's name, e.g. ``"tst"``.

    Returns
    -------
    pathlib.Path or None
    """
    if name in BUILTIN:
        return BUILTIN[name]
    if "/" in name or name.startswith("."):
        return None
    traced = published(cities_dir(), name, f"{name}_deployment.json")  # (a traced city's, in the store in use)
    return traced if traced.exists() else None


def named(name: str) -> Deployment:
    """A packaged deployment by name (``BUILTIN``), or a user's deployment file (``load_deployment``).

    Parameters
    ----------
    name : str
        A packaged deployment's name, or the path of a JSON or CSV file.

    Returns
    -------
    Deployment
    """
    path = builtin(name)
    return load_deployment(_published_file(Path(name)) if path is None else path)


def _published_file(path: Path) -> Path:
    """A traced city's deployment file (``<name>_deployment.json``) where a reader finds it while its city is being
    published (``_io.published``); any other file as it is."""
    if not path.name.endswith("_deployment.json"):
        return path
    return published(path.parent, path.name.removesuffix("_deployment.json"), path.name)


def tst() -> Deployment:
    """Our Tsim Sha Tsui-like deployment: 26 BSs at 10 m, 24 dBm, over a 476.8 m square (227,360 m²).

    Returns
    -------
    Deployment
    """
    return load_deployment(TST_FILE)


def digest(name: str) -> str:
    """SHA-256 of a deployment's file: the packaged file for a name of ``BUILTIN``, else the file at that path.

    Parameters
    ----------
    name : str
        A packaged deployment's name, or the path of a deployment file.

    Returns
    -------
    str
        Hex digest.

    Raises
    ------
    ValueError
        When ``name`` is none of these, or its file cannot be read.
    """
    path = builtin(name) or _published_file(Path(name))
    if path.suffix.lower() not in (".json", ".csv"):
        raise ValueError(f"deployment {name!r} names no packaged deployment ({', '.join(BUILTIN)}), no traced city of "
                         f"the results store in use (a city's deployment file missing: dpe5g trace traces it again), "
                         f"and no .json or .csv file")
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as err:
        raise ValueError(f"deployment file {name}: cannot be read ({err.strerror or err})") from None
