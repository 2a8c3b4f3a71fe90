"""Interactive 3-D scenes with meshcat, exported as one static HTML file (no server): the urban deployment
(``build``) and the ray-traced city (``build_city``: its buildings' triangles, the BSs, one UE and its traced paths).

In the urban deployment: buildings as boxes, BS masts as cylinders with a sphere on top, the UE, its links coloured LoS (green) / NLoS
(orange), and the DPE correlogram of the example fix as a surface above the UE.  meshcat's ``Visualizer`` normally
talks to a ZeroMQ server; here it talks to ``_Recorder``, which keeps the packed commands, and ``html`` wraps them
with meshcat's bundled viewer JavaScript into a page that works offline (the same page meshcat's server would give
for ``static_html()``).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..common._io import atomic_write

#: scene colours (0xRRGGBB)
COLOURS = {"building": 0x9aa4b1, "mast": 0x444444, "bs": 0xd62728, "ue": 0x1f77b4, "los": 0x2ca02c,
           "nlos": 0xff7f0e, "ground": 0xe8e8e0}
#: metres → viewer units (the region becomes about 2.9 units wide)
SCALE = 0.006
#: camera position in the viewer's y-up frame: south-west of the region, above it, looking at its centre
CAMERA = [-1.6, 2.4, 2.6]


class _Recorder:
    """Stands in for meshcat's ViewerWindow: records each command, packed exactly as the server would store it."""

    def __init__(self):
        self.commands: list[bytes] = []

    def send(self, command) -> None:
        import umsgpack  # (meshcat's: loaded only for a 3-D scene)

        self.commands.append(umsgpack.packb(command.lower()))


def _meshcat():
    """meshcat, imported without the DeprecationWarning its import of pyzmq's old tornado event loop raises (an
    error under the tests' warnings filter, and noise on a reader's console)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="zmq.eventloop.ioloop is deprecated", category=DeprecationWarning)
        import meshcat  # (meshcat: loaded only for a 3-D scene, its warning silenced)
        import meshcat.geometry  # noqa: F401  (the scene's objects)
        import meshcat.servers.zmqserver  # noqa: F401  (create_command)
    return meshcat


def _visualizer():
    meshcat = _meshcat()
    rec = _Recorder()
    return meshcat.Visualizer(window=rec), rec


def _scene(name: str, region):
    """A new recorded scene: its root node ``name`` scaled to viewer units, the camera set, a ground plate under the
    region (centred on the origin); returns (recorder, root node, meshcat.geometry, the material maker)."""
    top, rec = _visualizer()
    g = _meshcat().geometry
    vis = top[name]
    vis.set_transform(np.diag([SCALE, SCALE, SCALE, 1.0]))
    top["/Grid"].set_property("visible", False)
    top["/Cameras/default/rotated/<object>"].set_property("position", CAMERA)

    def mat(colour, opacity=1.0):
        return g.MeshLambertMaterial(color=colour, opacity=opacity, transparent=opacity < 1.0)

    x0, y0, x1, y1 = region
    vis["ground"].set_object(g.Box([x1 - x0, y1 - y0, 0.2]), mat(COLOURS["ground"]))
    vis["ground"].set_transform(_translation(0.0, 0.0, -0.1))
    return rec, vis, g, mat


def _translation(x, y, z):
    t = np.eye(4)
    t[:3, 3] = [x, y, z]
    return t


def build(payload7: dict, payload8: dict):
    """Build the scene from the payloads of Figs. 7 and 8, in local ENU metres with the region's centre at the origin.

    Parameters
    ----------
    payload7 : dict
        The Fig. 7 payload (``figure_data.deployment_payload``): deployment, example UE, links.
    payload8 : dict
        The Fig. 8 payload (``figure_data.urban_correlogram_payload``): the correlogram of the example fix.

    Returns
    -------
    _Recorder
        The recorder holding the scene's packed meshcat commands.
    """
    d7, d8 = payload7["data"], payload8["data"]
    rec, vis, g, mat = _scene("urban", d7["region"])
    x0, y0, x1, y1 = d7["region"]
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    for i, (bx0, by0, bx1, by1, h) in enumerate(d7["buildings"]):
        node = vis["buildings"][f"b{i:03d}"]
        node.set_object(g.Box([bx1 - bx0, by1 - by0, h]), mat(COLOURS["building"], 0.55))
        node.set_transform(_translation(0.5 * (bx0 + bx1) - cx, 0.5 * (by0 + by1) - cy, 0.5 * h))
    rot_z_up = np.array([[1, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)  # cylinder y → z
    for bid, (bx, by, bz) in zip(d7["bs_ids"], d7["bs_xyz"]):
        mast = vis["bs"][bid]["mast"]
        mast.set_object(g.Cylinder(bz, 1.5), mat(COLOURS["mast"]))
        mast.set_transform(_translation(bx - cx, by - cy, 0.5 * bz) @ rot_z_up)
        head = vis["bs"][bid]["antenna"]
        head.set_object(g.Sphere(5.0), mat(COLOURS["bs"]))
        head.set_transform(_translation(bx - cx, by - cy, bz))
    ue = d7["ue_xyz"]
    vis["ue"].set_object(g.Sphere(7.0), mat(COLOURS["ue"]))
    vis["ue"].set_transform(_translation(ue[0] - cx, ue[1] - cy, ue[2]))
    for j, (b, los) in enumerate(zip(d7["link_bs_xyz"], d7["link_los"])):
        pts = np.array([[ue[0] - cx, ue[1] - cy, ue[2]], [b[0] - cx, b[1] - cy, b[2]]], dtype=np.float32).T
        colour = COLOURS["los"] if los else COLOURS["nlos"]
        vis["links"][f"l{j:02d}"].set_object(g.Line(g.PointsGeometry(pts), g.LineBasicMaterial(color=colour,
                                                                                              linewidth=3)))
    # the correlogram of the example fix as a height field above the roofs over the UE, its ±10 m drawn ×5 wide
    xs, ys = np.asarray(d8["x_m"]), np.asarray(d8["y_m"])
    c = np.asarray(d8["cost_norm"])
    step = max(1, len(xs) // 60)
    xs, ys, c = xs[::step], ys[::step], c[::step, ::step]
    gx, gy = np.meshgrid(xs, ys)
    scale, lift = 5.0, 100.0
    verts = np.stack([(gx - ue[0]) * scale + ue[0] - cx, (gy - ue[1]) * scale + ue[1] - cy, lift + 40.0 * c],
                     axis=-1).reshape(-1, 3)
    ny, nx = c.shape
    ii = np.arange(ny - 1)[:, None] * nx + np.arange(nx - 1)[None, :]
    faces = np.concatenate([np.stack([ii, ii + 1, ii + nx + 1], -1).reshape(-1, 3),
                            np.stack([ii, ii + nx + 1, ii + nx], -1).reshape(-1, 3)])
    vis["correlogram"].set_object(g.TriangularMeshGeometry(verts.astype(np.float32), faces.astype(np.uint32)),
                                  g.MeshLambertMaterial(color=0x6a3d9a, opacity=0.85, transparent=True))
    return rec


def build_city(view: dict, region, bs_xyz, ue_xyz, los, paths_per_bs: int = 8):
    """Build the ray-traced city's scene: its buildings, the BSs, one UE and the traced paths from its BSs.

    Parameters
    ----------
    view : dict
        ``city_paths.load_view``: the buildings' triangles and the UE's traced paths.
    region : tuple of 4 float
        (x_min, y_min, x_max, y_max), metres: the scene is centred on it.
    bs_xyz : float (B, 3)
        Every BS, metres.
    ue_xyz : float (3,)
        The UE, metres.
    los : bool (J,)
        Whether each of the UE's links (``view["ue_bs"]``) is LoS.
    paths_per_bs : int
        The strongest paths drawn per BS.

    Returns
    -------
    _Recorder
        The recorder holding the scene's packed meshcat commands.
    """
    rec, vis, g, mat = _scene("city", region)
    x0, y0, x1, y1 = region
    centre = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0])
    tri = np.asarray(view["triangles"], dtype=np.float32) - centre.astype(np.float32)
    faces = np.arange(3 * len(tri), dtype=np.uint32).reshape(-1, 3)
    vis["buildings"].set_object(g.TriangularMeshGeometry(tri.reshape(-1, 3), faces), mat(COLOURS["building"], 0.55))
    for b, p in enumerate(np.asarray(bs_xyz) - centre):
        vis["bs"][f"C{b + 1:02d}"].set_object(g.Sphere(4.0), mat(COLOURS["bs"]))
        vis["bs"][f"C{b + 1:02d}"].set_transform(_translation(*p))
    vis["ue"].set_object(g.Sphere(5.0), mat(COLOURS["ue"]))
    vis["ue"].set_transform(_translation(*(np.asarray(ue_xyz) - centre)))
    pts, start = np.asarray(view["points"]) - centre, np.asarray(view["start"])
    power, bs = np.asarray(view["power_db"]), np.asarray(view["bs"])
    for j in range(len(view["ue_bs"])):
        mine = np.nonzero(bs == j)[0]
        colour = COLOURS["los"] if los[j] else COLOURS["nlos"]
        for n, i in enumerate(mine[np.argsort(-power[mine])][:paths_per_bs]):
            line = pts[start[i]:start[i + 1]].astype(np.float32).T
            vis["paths"][f"bs{j}"][f"p{n:02d}"].set_object(
                g.Line(g.PointsGeometry(line), g.LineBasicMaterial(color=colour, linewidth=2)))
    return rec


def html(rec: _Recorder) -> str:
    """The standalone page: meshcat's viewer JavaScript (bundled with the package) replaying the commands.

    Parameters
    ----------
    rec : _Recorder
        The recorder of ``build`` or ``build_city``.

    Returns
    -------
    str
        The HTML page.
    """
    meshcat = _meshcat()
    create_command = meshcat.servers.zmqserver.create_command  # what meshcat's own server emits for each command

    js = (Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js").read_text()
    cmds = "".join(create_command(c) for c in rec.commands)
    return ("<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>dpe5g: urban deployment (meshcat)</title>\n"
            "<style>body{margin:0} #meshcat-pane{width:100vw;height:100vh;overflow:hidden}</style></head>\n"
            "<body><div id=\"meshcat-pane\"></div>\n<script>" + js + "</script>\n<script>\n"
            "var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n" + cmds
            + "</script></body></html>\n")


def recorded_iframe(rec: _Recorder, title: str, height_px: int = 520) -> str:
    """A recorded scene (``build``, ``build_city``) as an ``<iframe srcdoc=...>`` element, self-contained.

    Parameters
    ----------
    rec : _Recorder
        The scene's recorder.
    title : str
        The frame's title (what a screen reader announces).
    height_px : int
        The frame's height, pixels (its width is the page's).

    Returns
    -------
    str
        The ``<iframe>`` element.
    """
    from meshcat.visualizer import srcdoc_escape  # (meshcat: loaded only for a 3-D scene)

    return (f'<iframe class="dpe5g-scene3d" title="{title}" srcdoc="{srcdoc_escape(html(rec))}" '
            f'style="width:100%;height:{height_px}px;border:1px solid #ccc"></iframe>')


def iframe(payload7: dict, payload8: dict, height_px: int = 520) -> str:
    """The scene as an ``<iframe srcdoc=...>`` element, self-contained, for embedding in a notebook or page.

    Parameters
    ----------
    payload7, payload8 : dict
        The Fig. 7 and Fig. 8 payloads, as for ``build``.
    height_px : int
        The frame's height, pixels (its width is the page's).

    Returns
    -------
    str
        The ``<iframe>`` element.
    """
    return recorded_iframe(build(payload7, payload8), "3-D scene of the urban deployment", height_px)


def export(payload7: dict, payload8: dict, path, exclusive: bool = False) -> Path:
    """Write the scene's static HTML to ``path`` atomically (``_io.atomic_write``).

    Parameters
    ----------
    payload7, payload8 : dict
        The Fig. 7 and Fig. 8 payloads, as for ``build``.
    path : str or pathlib.Path
        The HTML file to write.
    exclusive : bool
        Raise ``FileExistsError`` rather than replace an existing file.

    Returns
    -------
    pathlib.Path
        ``path``.
    """

    path = Path(path)
    atomic_write(path, html(build(payload7, payload8)).encode(), exclusive)
    return path
