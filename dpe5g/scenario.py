"""The urban scenario of Section III: the deployment, UMi street-canyon links (eq. (9), TR 38.901 path loss), the
link budget, and the UE clock bias.

Units: metres (local ENU: x east, y north, z up, origin at the region's south-west corner), dB / dBm, seconds, Hz.

The paper's 26 BS positions in Tsim Sha Tsui are not published.  ``tst()`` loads our layout with the paper's numbers
(26 BSs over a 227,360 m² square, BS height 10 m, 24 dBm) on a Tsim Sha Tsui-like street grid, made by
``scripts/make_layout.py``; ``load_deployment`` reads a user's deployment from JSON or CSV.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import _checks
from .nr import C, PAPER, Numerology

DATA_DIR = Path(__file__).resolve().parent / "data"
TST_FILE = DATA_DIR / "tst_deployment.json"

#: allowed ranges for a deployment's numbers
BS_HEIGHT_RANGE_M = (1.5, 150.0)  # TR 38.901 UMi: 10 m; the formulas need h_BS > h_E = 1 m
POWER_RANGE_DBM = (-30.0, 60.0)
MIN_BS = 3  # (x, y, c δt) has three unknowns


@dataclass(frozen=True, eq=False)
class Deployment:
    """Base stations over a rectangular region, with optional buildings and streets for the map and the 3-D scene.

    bs_ids : (B,) names; bs_xyz : (B, 3) m; power_dbm : (B,) transmit power per BS in dBm;
    region : (x_min, y_min, x_max, y_max) m; ue_height_m : UE height in m;
    buildings : (K, 5) rows (x_min, y_min, x_max, y_max, height) in m (may be empty);
    streets : tuple of dicts (name, axis, centre_m, width_m), for drawing only;
    anchor_lat_deg, anchor_lon_deg : WGS-84 position of the local origin, or None.
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

    @property
    def n_bs(self) -> int:
        return len(self.bs_ids)

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.region
        return (x1 - x0) * (y1 - y0)

    def check_ue(self, xy) -> np.ndarray:
        """Validate UE positions (..., 2) in metres: finite and inside the region."""
        xy = np.asarray(xy, dtype=np.float64)
        if xy.shape[-1:] != (2,) or not np.all(np.isfinite(xy)):
            raise ValueError(f"UE position must be finite (..., 2) metres, got shape {xy.shape}")
        x0, y0, x1, y1 = self.region
        inside = (xy[..., 0] >= x0) & (xy[..., 0] <= x1) & (xy[..., 1] >= y0) & (xy[..., 1] <= y1)
        if not np.all(inside):
            bad = xy[~inside].reshape(-1, 2)[0]
            raise ValueError(f"UE position must be inside the region x in [{x0:g}, {x1:g}] m, y in [{y0:g}, "
                             f"{y1:g}] m; got ({bad[0]:g}, {bad[1]:g})")
        return xy

    def nearest(self, ue_xy, m: int) -> np.ndarray:
        """Indices (..., m) of the m BSs nearest to the UE in 2-D distance, nearest first."""
        _checks.integer("m", m, 1, self.n_bs)
        d = np.linalg.norm(np.asarray(ue_xy)[..., None, :] - self.bs_xyz[:, :2], axis=-1)
        return np.argsort(d, axis=-1, kind="stable")[..., :m]


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
        pw.append(_number(source, where, "power_dbm", r["power_dbm"], *POWER_RANGE_DBM, "dBm"))
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
    y_max_m}, optional "ue_height_m", "buildings" [{x_min_m, y_min_m, x_max_m, y_max_m, height_m}], "streets",
    "anchor" {lat_deg, lon_deg}, "name", "description"}.
    Malformed files raise ``ValueError`` naming the file, the entry and the allowed range.
    """
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise ValueError(f"deployment file {src} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        try:
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
        except (OSError, UnicodeDecodeError, csv.Error) as e:
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
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        _fail(src, f"is not valid JSON ({e})")
    if not isinstance(doc, dict):
        _fail(src, "must hold a JSON object with base_stations and region")
    ids, xyz, pw = _base_stations(src, doc.get("base_stations"))
    reg = doc.get("region")
    if not isinstance(reg, dict):
        _fail(src, "needs a region {x_min_m, y_min_m, x_max_m, y_max_m}")
    region = tuple(_number(src, "region", k, reg.get(k), -1e5, 1e5, "m")
                   for k in ("x_min_m", "y_min_m", "x_max_m", "y_max_m"))
    if region[2] - region[0] < 1.0 or region[3] - region[1] < 1.0:
        _fail(src, f"region must have x_max_m > x_min_m and y_max_m > y_min_m (by at least 1 m), got {region}")
    outside = [b for b, p in zip(ids, xyz) if not (region[0] <= p[0] <= region[2] and region[1] <= p[1] <= region[3])]
    if outside:
        _fail(src, f"base station {outside[0]} lies outside the region {region}")
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
                      str(doc.get("description", "")))


def tst() -> Deployment:
    """Our Tsim Sha Tsui-like deployment: 26 BSs at 10 m, 24 dBm, over a 476.8 m square (227,360 m²)."""
    return load_deployment(TST_FILE)


# ---- links: TR 38.901 UMi street canyon ----------------------------------------------------------------------------

#: TR 38.901 Table 7.4.1-1 shadow-fading standard deviations, UMi street canyon, dB
SIGMA_SF_LOS_DB = 4.0
SIGMA_SF_NLOS_DB = 7.82
#: effective environment height h_E for the UMi breakpoint distance, m
H_E_M = 1.0


def los_probability(d2d_m) -> jax.Array:
    """Eq. (9) (TR 38.901 Table 7.4.2-1, UMi street canyon): Pr_LoS = 1 for D ≤ 18 m, else
    18/D + (1 - 18/D) e^{-D/36}.  d2d_m : (...) 2-D BS–UE distance in metres → (...) probability."""
    d = jnp.asarray(d2d_m, dtype=jnp.float64)
    safe = jnp.maximum(d, 18.0)
    return jnp.where(d <= 18.0, 1.0, 18.0 / safe + (1.0 - 18.0 / safe) * jnp.exp(-safe / 36.0))


def path_loss_umi_db(d2d_m, h_bs_m, h_ut_m, fc_hz, los) -> jax.Array:
    """TR 38.901 Table 7.4.1-1 UMi street-canyon path loss in dB (without shadow fading).

    LoS: PL1 = 32.4 + 21 log10(d3D) + 20 log10(fc) for d2D ≤ d'BP, PL2 = 32.4 + 40 log10(d3D) + 20 log10(fc)
    - 9.5 log10(d'BP² + (h_BS - h_UT)²) beyond, with d'BP = 4 (h_BS - 1)(h_UT - 1) fc / c.
    NLoS: max(PL_LoS, 35.3 log10(d3D) + 22.4 + 21.3 log10(fc) - 0.3 (h_UT - 1.5)).  fc in GHz inside the formulas.
    The table states the formulas for 10 m ≤ d2D ≤ 5 km; below 10 m we evaluate them at d2D = 10 m (stated in the
    book, not silent), so a UE at the foot of a mast does not get an unbounded SNR.
    d2d_m, los : (...) arrays; h_bs_m, h_ut_m : metres (broadcast); fc_hz : Hz.  Returns (...).
    """
    d2d = jnp.maximum(jnp.asarray(d2d_m, dtype=jnp.float64), 10.0)
    h_bs, h_ut = jnp.asarray(h_bs_m), jnp.asarray(h_ut_m)
    fc = fc_hz / 1e9
    d3d = jnp.sqrt(d2d**2 + (h_bs - h_ut) ** 2)
    d_bp = 4.0 * (h_bs - H_E_M) * (h_ut - H_E_M) * fc_hz / C
    pl1 = 32.4 + 21.0 * jnp.log10(d3d) + 20.0 * jnp.log10(fc)
    pl2 = 32.4 + 40.0 * jnp.log10(d3d) + 20.0 * jnp.log10(fc) - 9.5 * jnp.log10(d_bp**2 + (h_bs - h_ut) ** 2)
    pl_los = jnp.where(d2d <= d_bp, pl1, pl2)
    pl_nlos = jnp.maximum(pl_los, 35.3 * jnp.log10(d3d) + 22.4 + 21.3 * jnp.log10(fc) - 0.3 * (h_ut - 1.5))
    return jnp.where(jnp.asarray(los), pl_los, pl_nlos)


@dataclass(frozen=True)
class LinkBudget:
    """Link budget of the urban study: SNR = P_tx - PL - SF - (N0 + 10 log10 B + NF).

    fc_hz : carrier (the paper's Table I: 3 GHz); bandwidth_hz : 100 MHz (the paper's PRS band);
    noise_psd_dbm_hz : thermal noise density, -174 dBm/Hz; noise_figure_db : UE noise figure, 9 dB (our choice, the
    value TR 38.802 and the IMT-2020 evaluations use for a UE; the paper does not state one).
    """

    fc_hz: float = 3e9
    bandwidth_hz: float = 100e6
    noise_psd_dbm_hz: float = -174.0
    noise_figure_db: float = 9.0

    def __post_init__(self):
        _checks.in_range("fc_hz", self.fc_hz, 0.5e9, 100e9, "Hz")
        _checks.in_range("bandwidth_hz", self.bandwidth_hz, 1e6, 1e9, "Hz")
        _checks.in_range("noise_psd_dbm_hz", self.noise_psd_dbm_hz, -200.0, -100.0, "dBm/Hz")
        _checks.in_range("noise_figure_db", self.noise_figure_db, 0.0, 30.0, "dB")

    @property
    def noise_dbm(self) -> float:
        """Noise power in the band: -174 + 80 + 9 = -85 dBm with the defaults."""
        return self.noise_psd_dbm_hz + 10.0 * math.log10(self.bandwidth_hz) + self.noise_figure_db

    def snr_db(self, power_dbm, path_loss_db, shadow_db=0.0) -> jax.Array:
        """In-band SNR in dB: received power over the noise power in ``bandwidth_hz``."""
        return jnp.asarray(power_dbm) - jnp.asarray(path_loss_db) - jnp.asarray(shadow_db) - self.noise_dbm

    def model_snr_db(self, snr_inband_db, num: Numerology = PAPER) -> jax.Array:
        """Convert to the per-sample SNR of ``dpe5g.signal`` (noise over the sampled band N Δf = 122.88 MHz):
        SNR_model = SNR_inband - 10 log10(N Δf / B), i.e. 0.89 dB lower with the defaults."""
        return jnp.asarray(snr_inband_db) - 10.0 * math.log10(num.n_fft * num.scs_hz / self.bandwidth_hz)


def clock_bias(key, sigma_s: float, bound_sigmas: float, shape=()) -> jax.Array:
    """UE clock bias δt in seconds: Gaussian of standard deviation ``sigma_s`` truncated at ± bound_sigmas · sigma_s
    (the paper: σ = 5 ns after the coarse random-access synchronization; the bound is ours, 3 σ by default)."""
    return sigma_s * jax.random.truncated_normal(key, -bound_sigmas, bound_sigmas, shape, dtype=jnp.float64)


def toa_s(ue_xyz, bs_xyz) -> jax.Array:
    """Geometric ToA ‖ue - bs‖ / c in seconds; ue_xyz (..., 3), bs_xyz (..., B, 3) → (..., B)."""
    return jnp.linalg.norm(jnp.asarray(ue_xyz)[..., None, :] - jnp.asarray(bs_xyz), axis=-1) / C
