"""Generate the ring deployments of Chapter 3's studies (run once; the JSON files are committed).

Eight base stations evenly on a circle of radius 150 m around the origin (the first at 0.3 rad), 10 m high, 24 dBm;
the UE is drawn at 2 m height in a square at the centre: 10 m wide in ``ring_deployment.json`` (the receiver-window
study), 100 m wide in ``ring_wide_deployment.json`` (the window-centring study).  Every BS sees the UE from a
different side, so the geometry is as good as it gets; the studies use it to isolate the channel's effect.

    .venv/bin/python scripts/make_ring.py   # rewrites dpe5g/data/ring_deployment.json and ring_wide_deployment.json
"""

from __future__ import annotations

import json
import math
from pathlib import Path

N_BS = 8
RADIUS_M = 150.0
FIRST_ANGLE_RAD = 0.3
BS_HEIGHT_M = 10.0
POWER_DBM = 24.0
UE_HEIGHT_M = 2.0
REGION_HALF_M = 160.0
#: (file, name, UE square half-width in metres)
RINGS = (("ring_deployment.json", "ring", 5.0), ("ring_wide_deployment.json", "ring-wide", 50.0))


def ring(name: str, ue_half_m: float) -> dict:
    """The deployment document of one ring, in ``dpe5g.phy.deployment.load_deployment``'s JSON schema."""
    square = lambda h: {"x_min_m": -h, "y_min_m": -h, "x_max_m": h, "y_max_m": h}
    bss = []
    for i in range(N_BS):
        a = FIRST_ANGLE_RAD + 2 * math.pi * i / N_BS
        bss.append({"id": f"R{i + 1}", "x_m": RADIUS_M * math.cos(a), "y_m": RADIUS_M * math.sin(a),
                    "height_m": BS_HEIGHT_M, "power_dbm": POWER_DBM})
    return {"name": name,
            "description": (f"{N_BS} BSs evenly on a {RADIUS_M:g} m circle, the UE in a {2 * ue_half_m:g} m square at "
                            "its centre: Chapter 3's studies.  Made by scripts/make_ring.py."),
            "region": square(REGION_HALF_M), "ue_region": square(ue_half_m), "ue_height_m": UE_HEIGHT_M,
            "base_stations": bss}


def main():
    out = Path(__file__).resolve().parents[1] / "dpe5g" / "data"
    for file, name, half in RINGS:
        (out / file).write_text(json.dumps(ring(name, half), indent=1) + "\n")
        print(f"wrote {out / file}")


if __name__ == "__main__":
    main()
