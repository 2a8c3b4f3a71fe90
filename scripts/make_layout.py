"""Generate dpe5g/data/tst_deployment.json: our Tsim Sha Tsui-like deployment (run once; the JSON is committed).

The paper's BS coordinates are not public.  This script builds a layout with the paper's numbers — 26 BSs over a
227,360 m² square (476.8 m side), BS height 10 m, 24 dBm — on a street grid modelled loosely on Tsim Sha Tsui
(a wide north–south avenue like Nathan Road, narrower parallel streets, east–west cross streets about 80 m apart).
Street names are flavour only; positions are not surveyed.  BSs stand at the kerb of a street, picked from candidate
kerb points by a seeded Poisson-disk selection (minimum spacing below), building heights are seeded draws.

    .venv/bin/python scripts/make_layout.py   # rewrites dpe5g/data/tst_deployment.json
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

SEED = 2024
SIDE_M = math.sqrt(227_360.0)
N_BS = 26
MIN_SPACING_M = 72.0
# (centre, width, name): north-south streets at x = centre, east-west streets at y = centre, metres
NS_STREETS = [(20.0, 12.0, "Hankow Road"), (118.0, 30.0, "Nathan Road"), (222.0, 14.0, "Carnarvon Road"),
              (322.0, 14.0, "Hart Avenue"), (428.0, 18.0, "Chatham Road South")]
EW_STREETS = [(28.0, 16.0, "Salisbury Road"), (108.0, 12.0, "Peking Road"), (188.0, 12.0, "Haiphong Road"),
              (268.0, 14.0, "Kimberley Road"), (350.0, 12.0, "Granville Road"), (440.0, 14.0, "Austin Road")]


def blocks(streets, side):
    """Intervals between the streets along one axis (the building blocks), as (lo, hi)."""
    edges = [0.0] + [e for c, w, _ in streets for e in (c - w / 2, c + w / 2)] + [side]
    return [(edges[i], edges[i + 1]) for i in range(0, len(edges), 2) if edges[i + 1] - edges[i] > 5.0]


def main():
    rng = np.random.default_rng(SEED)
    side = SIDE_M
    buildings = []
    for x0, x1 in blocks(NS_STREETS, side):
        for y0, y1 in blocks(EW_STREETS, side):
            # split each block in two along its longer side with a 4 m service lane
            if x1 - x0 >= y1 - y0:
                xm = 0.5 * (x0 + x1)
                parts = [(x0, y0, xm - 2, y1), (xm + 2, y0, x1, y1)]
            else:
                ym = 0.5 * (y0 + y1)
                parts = [(x0, y0, x1, ym - 2), (x0, ym + 2, x1, y1)]
            for a, b, c, d in parts:
                buildings.append({"x_min_m": round(a, 2), "y_min_m": round(b, 2), "x_max_m": round(c, 2),
                                  "y_max_m": round(d, 2), "height_m": float(rng.integers(20, 91))})
    # candidate kerb points every 10 m along both kerbs of every street
    cand = []
    for c, w, _ in NS_STREETS:
        for s in (-1, 1):
            x = c + s * (w / 2 - 1.0)
            cand += [(x, y) for y in np.arange(5.0, side - 5.0, 10.0) if 1.0 <= x <= side - 1.0]
    for c, w, _ in EW_STREETS:
        for s in (-1, 1):
            y = c + s * (w / 2 - 1.0)
            cand += [(x, y) for x in np.arange(5.0, side - 5.0, 10.0) if 1.0 <= y <= side - 1.0]
    cand = np.array(cand)
    order = rng.permutation(len(cand))
    chosen = []
    for i in order:
        p = cand[i]
        if all(np.hypot(*(p - q)) >= MIN_SPACING_M for q in chosen):
            chosen.append(p)
        if len(chosen) == N_BS:
            break
    if len(chosen) < N_BS:
        raise SystemExit(f"only {len(chosen)} BSs fit at {MIN_SPACING_M} m spacing")
    chosen = sorted(chosen, key=lambda p: (round(p[1], 1), p[0]))
    out = {
        "name": "tst-like-26",
        "description": ("Our Tsim Sha Tsui-like layout with the paper's density and area (26 BSs over 227,360 m2, "
                        "476.8 m square); not the paper's coordinates, which are not public.  Made by "
                        "scripts/make_layout.py."),
        "anchor": {"lat_deg": 22.2960, "lon_deg": 114.1690,
                   "note": "WGS-84 position of the local ENU origin (x east, y north, metres) at the SW corner"},
        "region": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": round(side, 3), "y_max_m": round(side, 3)},
        "ue_height_m": 2.0,
        "base_stations": [{"id": f"BS{i + 1:02d}", "x_m": round(float(p[0]), 2), "y_m": round(float(p[1]), 2),
                           "height_m": 10.0, "power_dbm": 24.0} for i, p in enumerate(chosen)],
        "buildings": buildings,
        "streets": ([{"name": n, "axis": "north-south", "centre_m": c, "width_m": w} for c, w, n in NS_STREETS]
                    + [{"name": n, "axis": "east-west", "centre_m": c, "width_m": w} for c, w, n in EW_STREETS]),
    }
    path = Path(__file__).resolve().parent.parent / "dpe5g" / "data" / "tst_deployment.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}: {len(chosen)} BSs, {len(buildings)} buildings")


if __name__ == "__main__":
    main()
