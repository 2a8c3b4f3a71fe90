"""The deployment of Section III: base stations (position, height, power, ID), the region, buildings and streets,
read from a file and validated.

Units: metres (local ENU: x east, y north, z up, origin at the region's south-west corner), dBm.

The paper's 26 BS positions in Tsim Sha Tsui are not published.  ``tst()`` loads our layout with the paper's numbers
(26 BSs over a 227,360 m² square, BS height 10 m, 24 dBm) on a Tsim Sha Tsui-like street grid, made by
``scripts/make_layout.py``; ``load_deployment`` reads a user's deployment from JSON or CSV.  The propagation models
that act on a deployment (eq. (11), the path loss, the link budget, the clock bias) are in ``dpe5g.scenario``.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _checks

DATA_DIR = Path(__file__).resolve().parent / "data"
TST_FILE = DATA_DIR / "tst_deployment.json"
#: the deployments packaged with dpe5g, by name (``builtin``): our Tsim Sha Tsui-like layout, and the rings of
#: Chapter 3's studies (8 BSs on a 150 m circle, the UE in a 10 m or a 100 m square at its centre), made by
#: ``scripts/make_ring.py``
BUILTIN = {"tst": TST_FILE, "ring": DATA_DIR / "ring_deployment.json", "ring-wide": DATA_DIR / "ring_wide_deployment.json"}

#: allowed ranges for a deployment's numbers
BS_HEIGHT_RANGE_M = (1.5, 150.0)  # TR 38.901 UMi: 10 m; the formulas need h_BS > h_E = 1 m
#: a BS transmit power in dBm: 10 dBm (a femtocell) to 60 dBm (1 kW, above any macro cell's 46-49 dBm); a value
#: below 10 is most likely in watts (24 dBm is 0.25 W)
POWER_RANGE_DBM = (10.0, 60.0)
MIN_BS = 3  # (x, y, c δt) has three unknowns


@dataclass(frozen=True, eq=False)
class Deployment:
    """Base stations over a rectangular region, with optional buildings and streets for the map and the 3-D scene.

    bs_ids : (B,) names; bs_xyz : (B, 3) m; power_dbm : (B,) transmit power per BS in dBm;
    region : (x_min, y_min, x_max, y_max) m; ue_height_m : UE height in m;
    buildings : (K, 5) rows (x_min, y_min, x_max, y_max, height) in m (may be empty);
    streets : tuple of dicts (name, axis, centre_m, width_m), for drawing only;
    anchor_lat_deg, anchor_lon_deg : WGS-84 position of the local origin, or None.
    ue_region : (x_min, y_min, x_max, y_max) m, inside ``region``: where the UE is drawn, or None for the whole
        region (``ue_bounds``).
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

    @property
    def ue_bounds(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max) m of the area the UE is drawn from: ``ue_region``, else the region."""
        return self.region if self.ue_region is None else self.ue_region

    @property
    def n_bs(self) -> int:
        return len(self.bs_ids)

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.region
        return (x1 - x0) * (y1 - y0)

    def check_ue(self, xy) -> np.ndarray:
        """Validate UE positions (..., 2) in metres: finite and inside the UE's area (``ue_bounds``)."""
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
        """The PRS resource and ID of every BS for frequency reuse ``reuse`` (``prs_plan``)."""
        return prs_plan(self.bs_xyz, reuse)

    def nearest(self, ue_xy, m: int) -> np.ndarray:
        """Indices (..., m) of the m BSs nearest to the UE in 2-D distance, nearest first."""
        _checks.integer("m", m, 1, self.n_bs)
        d = np.linalg.norm(np.asarray(ue_xy)[..., None, :] - self.bs_xyz[:, :2], axis=-1)
        return np.argsort(d, axis=-1, kind="stable")[..., :m]


#: PRS sequence IDs n_ID^PRS per resource, 0 … 4095 (TS 38.211 §7.4.1.7.2)
N_PRS_IDS = 4096


def prs_plan(bs_xyz, reuse: int) -> tuple[np.ndarray, np.ndarray]:
    """PRS frequency reuse: each BS gets one of ``reuse`` orthogonal resources and a PRS ID.

    The resources are the comb offsets 0 … reuse − 1 of a comb of size ``reuse`` (``nr.PrsPattern(reuse)``): in the
    fully staggered pattern every offset still covers the whole band, so each link keeps the paper's resolution, and
    the offsets never share an RE.  The assignment colours the BS graph greedily, in the order of the deployment: each
    BS takes the resource whose nearest BS already holding it is farthest away (ties: the lowest resource), so the
    first ``reuse`` BSs take distinct resources and near neighbours differ.  Its PRS ID n_ID is its rank among the
    BSs of its resource (0, 1, …), so co-channel BSs carry different sequences.

    bs_xyz : (B, 3) metres; reuse : in ``nr.PRS_COMB_SIZES``.  Returns (resource (B,) int, prs_id (B,) int).
    Deterministic: a function of the BS positions and their order.
    """
    from . import nr

    _checks.one_of("reuse", reuse, nr.PRS_COMB_SIZES)
    xy = np.asarray(bs_xyz, dtype=np.float64)[:, :2]
    n_bs = xy.shape[0]
    if n_bs > reuse * N_PRS_IDS:
        raise ValueError(f"n_bs must be at most reuse × PRS IDs = {reuse} × {N_PRS_IDS} = {reuse * N_PRS_IDS} for "
                         f"reuse {reuse}, got {n_bs} base stations")
    res = np.zeros(n_bs, dtype=int)
    nearest = np.full((n_bs, reuse), np.inf)  # nearest[b, r]: distance from b to the closest BS on resource r so far
    for b in range(n_bs):
        score = np.where(np.bincount(res[:b], minlength=reuse) < N_PRS_IDS, nearest[b], -np.inf)
        res[b] = int(np.argmax(score))
        nearest[:, res[b]] = np.minimum(nearest[:, res[b]], np.linalg.norm(xy - xy[b], axis=-1))
    ids = np.array([np.count_nonzero(res[:b] == res[b]) for b in range(n_bs)], dtype=int)
    return res, ids


def _fail(source, msg):
    raise ValueError(f"deployment file {source}: {msg}")


def _number(source, where, key, value, lo, hi, unit):
    try:
        v = float(value)
    except (TypeError, ValueError):
        _fail(source, f"{where}: {key} must be a number in [{lo:g}, {hi:g}] {unit}, got {value!r}")
    if not math.isfinite(v) or not lo <= v <= hi:
        _fail(source, f"{where}: {key} must be in [{lo:g}, {hi:g}] {unit}, got {value!r}")
    return v


def _power(source, where, value):
    """A BS transmit power in dBm within ``POWER_RANGE_DBM``; the error suggests watts for small positive values."""
    lo, hi = POWER_RANGE_DBM
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if math.isfinite(v) and lo <= v <= hi:
        return v
    hint = ""
    if math.isfinite(v) and 0 < v < lo:
        hint = (f" — {v:g} dBm is {10 ** (v / 10):.3g} mW, not a base station; looks like watts? "
                f"{v:g} W is {10 * math.log10(v * 1e3):.1f} dBm")
    _fail(source, f"{where}: power_dbm must be in [{lo:g}, {hi:g}] dBm (a BS transmit power), got {value!r}{hint}")


def _base_stations(source, rows):
    """Validate BS rows (dicts with id, x_m, y_m, height_m, power_dbm) → ids, xyz, power."""
    if not isinstance(rows, list) or len(rows) < MIN_BS:
        n = len(rows) if isinstance(rows, list) else 0
        _fail(source, f"needs at least {MIN_BS} base stations (x, y and the clock bias are unknown), got {n}")
    ids, xyz, pw = [], [], []
    for i, r in enumerate(rows):
        where = f"base station {i + 1}"
        if not isinstance(r, dict):
            _fail(source, f"{where} must be an object with id, x_m, y_m, height_m, power_dbm")
        missing = [k for k in ("x_m", "y_m", "height_m", "power_dbm") if k not in r or r[k] in ("", None)]
        if missing:
            _fail(source, f"{where}: missing {', '.join(missing)}")
        bid = str(r.get("id") or f"BS{i + 1:02d}")
        if bid in ids:
            _fail(source, f"{where}: duplicate id {bid!r}")
        ids.append(bid)
        xyz.append([_number(source, where, "x_m", r["x_m"], -1e5, 1e5, "m"),
                    _number(source, where, "y_m", r["y_m"], -1e5, 1e5, "m"),
                    _number(source, where, "height_m", r["height_m"], *BS_HEIGHT_RANGE_M, "m")])
        pw.append(_power(source, f"{where} ({bid})", r["power_dbm"]))
    xyz = np.array(xyz)
    d = np.linalg.norm(xyz[:, None, :2] - xyz[None, :, :2], axis=-1) + np.eye(len(ids)) * 1e9
    if d.min() < 0.5:
        i, j = np.unravel_index(np.argmin(d), d.shape)
        _fail(source, f"base stations {ids[i]} and {ids[j]} are less than 0.5 m apart")
    return tuple(ids), xyz, np.array(pw)


def load_deployment(path) -> Deployment:
    """Read a deployment from JSON (our schema, see ``dpe5g/data/tst_deployment.json``) or CSV.

    CSV: a header row with columns id, x_m, y_m, height_m, power_dbm (id optional), one BS per row; the region is
    then the BSs' bounding box grown by 10 % on each side and the UE height 2 m.
    JSON: {"base_stations": [{id, x_m, y_m, height_m, power_dbm}, ...], "region": {x_min_m, y_min_m, x_max_m,
    y_max_m}, optional "ue_region" (the same keys, inside the region: where the UE is drawn), "ue_height_m",
    "buildings" [{x_min_m, y_min_m, x_max_m, y_max_m, height_m}], "streets",
    "anchor" {lat_deg, lon_deg}, "name", "description"}.
    Malformed files raise ``ValueError`` naming the file, the entry and the allowed range.
    """
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise ValueError(f"deployment file {src} does not exist")
    if not path.is_file():
        raise ValueError(f"deployment file {src} is not a file")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        try:
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
        except OSError as e:
            _fail(src, f"cannot be read ({e.strerror or e})")
        except (UnicodeDecodeError, csv.Error) as e:
            _fail(src, f"cannot be read as CSV ({e})")
        if rows and None in rows[0]:
            _fail(src, "a row has more fields than the header")
        ids, xyz, pw = _base_stations(src, rows)
        lo, hi = xyz[:, :2].min(0), xyz[:, :2].max(0)
        pad = 0.1 * max(float(np.max(hi - lo)), 1.0)
        region = (lo[0] - pad, lo[1] - pad, hi[0] + pad, hi[1] + pad)
        return Deployment(path.stem, ids, xyz, pw, tuple(float(v) for v in region))
    if suffix != ".json":
        _fail(src, f"must end in .json or .csv, got {path.suffix!r}")
    try:
        text = path.read_bytes()  # json.loads detects the UTF encoding; a bad one is a decode error below
    except OSError as e:
        _fail(src, f"cannot be read ({e.strerror or e})")
    try:
        doc = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        _fail(src, f"is not valid JSON ({e})")
    if not isinstance(doc, dict):
        _fail(src, "must hold a JSON object with base_stations and region")
    ids, xyz, pw = _base_stations(src, doc.get("base_stations"))
    if not isinstance(doc.get("region"), dict):
        _fail(src, "needs a region {x_min_m, y_min_m, x_max_m, y_max_m}")
    region = _rectangle(src, "region", doc["region"])
    outside = [b for b, p in zip(ids, xyz) if not (region[0] <= p[0] <= region[2] and region[1] <= p[1] <= region[3])]
    if outside:
        _fail(src, f"base station {outside[0]} lies outside the region {region}")
    ue_region = None
    if doc.get("ue_region") is not None:
        ue_region = _rectangle(src, "ue_region", doc["ue_region"])
        if any(ue_region[i] < region[i] for i in (0, 1)) or any(ue_region[i] > region[i] for i in (2, 3)):
            _fail(src, f"ue_region {ue_region} must lie inside the region {region}")
    ue_h = _number(src, "ue_height_m", "ue_height_m", doc.get("ue_height_m", 2.0), 1.0, 22.5, "m")
    blds = []
    for i, b in enumerate(doc.get("buildings", [])):
        keys = ("x_min_m", "y_min_m", "x_max_m", "y_max_m", "height_m")
        if not isinstance(b, dict) or any(k not in b for k in keys):
            _fail(src, f"building {i + 1} needs {', '.join(keys)}")
        row = [_number(src, f"building {i + 1}", k, b[k], -1e5, 1e5, "m") for k in keys]
        if row[2] <= row[0] or row[3] <= row[1] or row[4] <= 0:
            _fail(src, f"building {i + 1} must have x_max_m > x_min_m, y_max_m > y_min_m and height_m > 0")
        blds.append(row)
    anchor = doc.get("anchor") or {}
    lat = anchor.get("lat_deg")
    lon = anchor.get("lon_deg")
    if lat is not None:
        lat = _number(src, "anchor", "lat_deg", lat, -90, 90, "deg")
        lon = _number(src, "anchor", "lon_deg", lon, -180, 180, "deg")
    return Deployment(str(doc.get("name", path.stem)), ids, xyz, pw, region, ue_h,
                      np.array(blds).reshape(-1, 5), tuple(doc.get("streets", [])), lat, lon,
                      str(doc.get("description", "")), ue_region)


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
    """The file of the packaged deployment ``name`` (``BUILTIN``), or None if ``name`` is not one of them."""
    return BUILTIN.get(name)


def named(name: str) -> Deployment:
    """A packaged deployment by name (``BUILTIN``), or a user's deployment file (``load_deployment``)."""
    path = builtin(name)
    return load_deployment(name if path is None else path)


def tst() -> Deployment:
    """Our Tsim Sha Tsui-like deployment: 26 BSs at 10 m, 24 dBm, over a 476.8 m square (227,360 m²)."""
    return load_deployment(TST_FILE)


# ---- links: TR 38.901 UMi street canyon ----------------------------------------------------------------------------
