"""The ray-traced city's 3-D view: the buildings of its region and one UE's traced paths as polylines, for
``scene3d.build_city`` (``dpe5g trace`` writes them to the results store, ``dataset.save_view``).

Units: metres, dB.
"""

from __future__ import annotations

import numpy as np

from .ray_tracer import solve_paths
from .trace import CitySpec


def scene_triangles(scene, region, margin_m: float = 20.0) -> np.ndarray:
    """The scene's triangles whose centre lies in ``region`` widened by ``margin_m`` (the 3-D view's buildings).

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres.
    margin_m : float
        How far outside the region triangles are kept, metres.

    Returns
    -------
    float32 (T, 3, 3)
        The triangles' corners, metres.
    """
    x0, y0, x1, y1 = region
    out = []
    for shape in scene.mi_scene.shapes():
        v = np.asarray(shape.vertex_positions_buffer()).reshape(-1, 3)
        tri = v[np.asarray(shape.faces_buffer()).reshape(-1, 3)]
        c = tri.mean(axis=1)
        keep = (c[:, 0] > x0 - margin_m) & (c[:, 0] < x1 + margin_m) & (c[:, 1] > y0 - margin_m) & (
            c[:, 1] < y1 + margin_m) & (c[:, 2] > 0.1)  # not the ground plane
        out.append(tri[keep])
    return np.concatenate(out).astype(np.float32)


def example_paths(scene, bs_xyz, ue_xyz, spec: CitySpec) -> dict:
    """One UE's traced paths from the BSs ``bs_xyz`` as polylines (BS, interaction points, UE), for the 3-D view: of
    each BS's, the first and the strongest others, ``spec.n_paths`` in all (the paths a link keeps, ``compact_links``).

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene (``load_scene``).
    bs_xyz : float (J, 3)
        The BSs, metres.
    ue_xyz : float (3,)
        The UE, metres.
    spec : CitySpec
        The solver's settings (as ``trace_links``).

    Returns
    -------
    dict
        "points" float32 (P, 3) metres, the polylines one after another; "start" int (n + 1,), where each polyline
        starts in "points" (and the end); "bs" int (n,), its BS (index into bs_xyz); "power_db" float32 (n,), its path
        gain, dB.
    """
    paths = solve_paths(scene, bs_xyz, ue_xyz, spec)
    a, _ = paths.cir(normalize_delays=False, out_type="numpy")
    a = a[0, 0, :, 0, :, 0]  # (J, P)
    kinds = np.asarray(paths.interactions.numpy())[:, 0]  # (depth, J, P)
    verts = np.asarray(paths.vertices.numpy())[:, 0]  # (depth, J, P, 3)
    valid = np.asarray(paths.valid.numpy())[0] & (np.abs(a) > 0)
    tau = np.where(valid, np.asarray(paths.tau.numpy())[0], np.inf)  # (J, P)
    rank = np.where(valid, np.abs(a) ** 2, -1.0)
    rank[np.arange(len(rank)), np.argmin(tau, axis=1)] = np.inf
    kept = np.zeros_like(valid)
    np.put_along_axis(kept, np.argsort(-rank, axis=1, kind="stable")[:, :spec.n_paths], True, axis=1)
    valid &= kept
    pts, start, bs, power = [], [0], [], []
    for j, p in zip(*np.nonzero(valid)):
        hops = [verts[k, j, p] for k in range(kinds.shape[0]) if kinds[k, j, p] != 0]
        line = np.vstack([bs_xyz[j], *hops, ue_xyz]) if hops else np.vstack([bs_xyz[j], ue_xyz])
        pts.append(line)
        start.append(start[-1] + len(line))
        bs.append(j)
        power.append(10 * np.log10(np.abs(a[j, p]) ** 2))
    return {"points": np.vstack(pts).astype(np.float32), "start": np.asarray(start), "bs": np.asarray(bs),
            "power_db": np.asarray(power, np.float32)}
