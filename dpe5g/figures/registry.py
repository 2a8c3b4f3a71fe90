"""The one place where the paper's figures are registered.

Each figure has one ``compute`` function in ``figure_data`` (config + seed → JSON-able payload of every plotted
number) and one ``plot`` function in ``plots`` or ``result_plots`` (payload → matplotlib Figure).  ``make figures`` (``dpe5g figures``), the
figure-diff test and the book's chapters all go through ``REGISTRY``, so they cannot drift apart.

Payload layout: ``{"id", "paper_ref", "caption", "seed", "config": {...}, "data": {...}}``.

``compute`` keeps each payload in the cache (``payload_path``) keyed by the code of the whole package, so within
one state of the code a payload is computed once: by the first chapter that shows it, then read by the other
chapters, the figure-diff and ``make figures``.  The statistics come from ``results``, the Markdown tables of the
readings from ``report``.
"""

from __future__ import annotations

import hashlib
import inspect
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from matplotlib.figure import Figure

from ..common._io import atomic_target, atomic_write, jsonable
from ..simulation import chunk_cache, code_key, store
from ..studies import paper
from . import data as figure_data, plots, result_plots


@dataclass(frozen=True)
class FigureSpec:
    """A registered figure.

    Attributes
    ----------
    id : str
        The figure's id, e.g. ``"fig09_rmse_vs_snr"``.
    paper_ref : str or None
        The paper's figure, e.g. ``"Fig. 9"``; None: not a figure of the paper (the readings table).
    caption : str
        The caption.
    compute : callable
        Its producer: () → payload without id, ``paper_ref`` and caption (see the module).
    plot : callable
        Its drawing: payload → matplotlib Figure.
    """

    id: str
    paper_ref: str | None  # None: not a figure of the paper (the readings table)
    caption: str
    compute: Callable[[], dict]
    plot: Callable[[dict], Any]


REGISTRY: dict[str, FigureSpec] = {}


def register(fig_id: str, paper_ref: str | None, caption: str, plot: Callable[[dict], Any]):
    """Decorator registering ``compute`` as the producer of figure ``fig_id``.

    Parameters
    ----------
    fig_id, paper_ref, caption, plot
        The ``FigureSpec`` fields ``id``, ``paper_ref``, ``caption`` and ``plot``.

    Returns
    -------
    callable
        The decorator: it registers ``compute`` and returns it unchanged; ``ValueError`` when ``fig_id`` is taken.
    """

    def wrap(compute: Callable[[], dict]) -> Callable[[], dict]:
        if fig_id in REGISTRY:
            raise ValueError(f"figure id {fig_id!r} registered twice")
        REGISTRY[fig_id] = FigureSpec(fig_id, paper_ref, caption, compute, plot)
        return compute

    return wrap


def get(fig_id: str) -> FigureSpec:
    """The registered figure ``fig_id``.

    Parameters
    ----------
    fig_id : str
        A key of ``REGISTRY``.

    Returns
    -------
    FigureSpec

    Raises
    ------
    ValueError
        When ``fig_id`` is not registered.
    """
    if fig_id not in REGISTRY:
        raise ValueError(f"figure must be one of {', '.join(REGISTRY)}; got {fig_id!r}")
    return REGISTRY[fig_id]


def takes_trials(fig_id: str) -> bool:
    """Whether the figure comes from a Monte Carlo whose trial count ``compute(..., trials=N)`` can set.

    Parameters
    ----------
    fig_id : str
        A key of ``REGISTRY``.

    Returns
    -------
    bool
    """
    return "trials" in inspect.signature(get(fig_id).compute).parameters


def compute(fig_id: str, progress: bool = False, trials: int | None = None) -> dict:
    """Run the producer of ``fig_id``, or read its payload from the store where this code computed it before.

    Read by ``load_payload``: the Monte Carlo figures then need no Monte Carlo results either.

    Parameters
    ----------
    fig_id : str
        A key of ``REGISTRY``.
    progress : bool
        Show a progress bar (stderr) where the producer runs a long Monte Carlo (the CLI turns it on).
    trials : int or None
        Monte Carlo trials per experiment instead of the committed figure's (``dpe5g.studies.paper``); only for the figures
        of ``takes_trials``.  The payload then differs from the committed baseline.

    Returns
    -------
    dict
        The JSON-able payload.

    Raises
    ------
    ValueError
        When ``fig_id`` is unknown, or ``trials`` is given for a figure without a Monte Carlo.
    """
    spec = get(fig_id)
    kwargs = {}
    if "progress" in inspect.signature(spec.compute).parameters:
        kwargs["progress"] = progress
    if trials is not None:
        if not takes_trials(fig_id):
            raise ValueError(f"trials: figure {fig_id} has no Monte Carlo; trials applies to "
                             f"{', '.join(f for f in REGISTRY if takes_trials(f))}")
        kwargs["trials"] = int(trials)
    stored = load_payload(fig_id, kwargs.get("trials"))
    if stored is not None:
        return stored
    payload = spec.compute(**kwargs)
    return save_payload(fig_id, kwargs.get("trials"),
                              {"id": spec.id, "paper_ref": spec.paper_ref, "caption": spec.caption, **payload})


def render(payload: dict):
    """Draw a payload with its registered plot function.

    Parameters
    ----------
    payload : dict
        A payload of ``compute``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    return get(payload["id"]).plot(payload)


#: the environment variable the book build sets (``book/_ext/dpe5g_book.py``): a chapter's kernel then hands its
#: numbers and figures to the book only; re-executed as a notebook (``make chapter``, ``make lab``) it shows them too
BOOK_BUILD_ENV = "DPE5G_BOOK_BUILD"


def in_book_build() -> bool:
    """Whether this process runs inside the book build (``BOOK_BUILD_ENV``).

    Returns
    -------
    bool
    """
    return os.environ.get(BOOK_BUILD_ENV) == "1"


def glue_value(name: str, value, display: bool = False) -> None:
    """Hand a number or a text to a chapter's prose (``{glue:text}``, MyST-NB glue); outside the book build also
    show it in the cell's output as ``name = value``, where a notebook cannot fill the prose's placeholder.

    Parameters
    ----------
    name : str
        The glue name the chapter refers to.
    value : int, float, str or object
        What the prose shows (an object other than a number or a text is displayed as it is).
    display : bool
        Whether the book shows it where it is glued too (MyST-NB's ``display``).
    """
    from myst_nb import glue as _glue  # (the book's: loaded only in a chapter's kernel)

    _glue(name, value, display=display)
    if not (display or in_book_build()):
        _show(name, value)


def _show(name: str, value) -> None:
    """``name = value`` for a number or a text, else the object, in the cell's output."""
    from IPython.display import display as show

    if isinstance(value, (int, float, str, np.number)):
        print(f"{name} = {value}")
    else:
        print(f"{name}:")
        show(value)


def glue(name: str, fig) -> None:
    """Hand a drawn figure (or any displayable object, e.g. HTML) to a chapter's ``{glue:figure}`` directive
    (MyST-NB glue); a matplotlib Figure must pass ``plots.check_legible`` (text ≥ 9 pt, shown unshrunk).  The
    chapter writes the caption, with any number in it glued as ``{glue:text}``::

        ```{glue:figure} name
        :name: fig-name
        **Reproduces the paper's Fig. 9.** RMSE against SNR …
        ```

    Parameters
    ----------
    name : str
        The glue name the chapter refers to.
    fig : matplotlib.figure.Figure or object
        The figure, or any displayable object.
    """
    from myst_nb import glue as _glue  # (the book's: loaded only in a chapter's kernel)

    if isinstance(fig, Figure):
        plots.check_legible(fig)
    _glue(name, fig, display=False)
    if not in_book_build():  # (a notebook: shown where the book's caption would be)
        _show(name, fig)


def write(fig_id: str, out_dir, progress: bool = False, trials: int | None = None) -> tuple[Path, Path]:
    """Compute and draw ``fig_id``; write ``out_dir/<id>.png`` and ``out_dir/data/<id>.json``.

    The figure is drawn and checked (``plots.save_png`` checks its legibility) before either file is written, so a
    figure that fails leaves both files as they were.

    Parameters
    ----------
    fig_id, progress, trials
        As for ``compute``.
    out_dir : str or pathlib.Path
        The output folder.

    Returns
    -------
    png, js : pathlib.Path
        The files written.
    """
    out = Path(out_dir)
    payload = compute(fig_id, progress=progress, trials=trials)
    js, png = out / "data" / f"{fig_id}.json", out / f"{fig_id}.png"
    fig = render(payload)
    with atomic_target(png) as tmp:
        plots.save_png(fig, tmp)  # format="png" is explicit, so the ".tmp" name does not matter
        atomic_write(js, (json.dumps(payload, indent=1, sort_keys=True) + "\n").encode())
    return png, js


def payload_path(fig_id: str, trials: int | None = None, cache=None) -> Path:
    """Where ``figures.compute`` keeps a figure's payload: ``<cache root>/payloads/<id>-<key>.json``.

    The key hashes the figure id, the trial count, the code of every module of the package (``code_key.code_digest``:
    docstrings and comments left out), its data files, the numerical libraries' versions and the results store's content
    (``store.store_digest``): everything a payload is computed from, so a stored payload is exactly what computing it again
    would give, and any change of code or of the store computes it anew.

    Parameters
    ----------
    fig_id : str
        The figure's id.
    trials : int or None
        Its Monte Carlo trials; None: the committed figure's.
    cache : str, os.PathLike or None
        The cache root (``cache_root``), beside the Monte Carlo results.

    Returns
    -------
    Path
        The payload's file.
    """
    here = Path(__file__).resolve().parents[1]  # the package's folder
    h = hashlib.sha256(json.dumps([fig_id, trials, code_key.numerics()], sort_keys=True).encode())
    for path in sorted(here.rglob("*.py")):  # every module, in the subpackages too, by its path inside the package
        h.update(path.relative_to(here).as_posix().encode() + code_key.code_digest(path))
    for path in sorted(p for p in (here / "data").rglob("*") if p.is_file()):
        h.update(path.name.encode() + path.read_bytes())
    h.update(store.store_digest().encode())
    return chunk_cache.cache_root(cache) / "payloads" / f"{fig_id}-{h.hexdigest()[:16]}.json"


def load_payload(fig_id: str, trials: int | None = None, cache=None) -> dict | None:
    """The stored payload of a figure (``payload_path``).

    Parameters
    ----------
    fig_id, trials, cache
        As for ``payload_path``.

    Returns
    -------
    dict or None
        The payload; None when this code has not computed it, or when its file is damaged or fails its checksum (named
        on stderr and set aside as ``<name>.damaged``, so it is computed again).
    """
    path = payload_path(fig_id, trials, cache)
    try:
        held = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:  # (never computed, or another process set it aside meanwhile)
        return None
    except ValueError as err:  # (UnicodeDecodeError included)
        return chunk_cache.set_aside(path, f"not valid JSON: {' '.join(str(err).split())}")
    if not isinstance(held, dict) or held.get("sha256") != payload_digest(held.get("payload")):
        return chunk_cache.set_aside(path, "its payload does not match its checksum")
    return held["payload"]


def payload_digest(payload) -> str:
    """SHA-256 of a payload's JSON (keys sorted): the checksum ``save_payload`` records.

    Parameters
    ----------
    payload : dict
        The payload, JSON-able.

    Returns
    -------
    str
        The hex digest.
    """
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def save_payload(fig_id: str, trials: int | None, payload: dict, cache=None) -> dict:
    """Store a payload as JSON (``jsonable``) with its checksum (``payload_digest``, checked by ``load_payload``).

    Parameters
    ----------
    fig_id, trials, cache
        As for ``payload_path``, where it is written atomically.
    payload : dict
        The payload.

    Returns
    -------
    dict
        What was stored: the payload made ``jsonable``.
    """
    payload = jsonable(payload)
    held = {"sha256": payload_digest(payload), "payload": payload}
    atomic_write(payload_path(fig_id, trials, cache), json.dumps(held).encode())
    return payload


# ---------------------------------------------------------------------------------------------------------------
# The paper's figures (each payload's producer is in ``figure_data``) and the readings table.

def _register_tdl(number: int, letter: str, condition: str) -> None:
    caption = (
        f"TDL-{letter} channel model for {condition} condition generated with a desired RMS delay spread of 65 ns. "
        "(a) is the channel impulse response of the TDL model, (b) is the power delay profile."
    )
    register(f"fig0{number}_tdl_{letter.lower()}", f"Fig. {number}", caption, plots.plot_tdl)(
        lambda: figure_data.tdl_payload(letter)
    )


for _n, _l, _c in ((1, "A", "NLoS"), (2, "B", "NLoS"), (3, "C", "NLoS"), (4, "D", "LoS"), (5, "E", "LoS")):
    _register_tdl(_n, _l, _c)

register("fig06_cost_surface", "Fig. 6",
         "Cost function composed of signals from 8 BSs, each propagating through an equally spaced 3-tap NLoS channel.",
         plots.plot_cost_surface)(figure_data.cost_surface_payload)

register("fig07_deployment_map", "Fig. 7",
         "Our Tsim Sha Tsui-like deployment: 26 BSs over a 227,360 m² region, and an example UE with its 12 "
         "nearest links (LoS/NLoS drawn from eq. (11)).", plots.plot_deployment)(figure_data.deployment_payload)

register("fig08_urban_correlogram", "Fig. 8",
         "2-D correlogram (eq. (10), the 12 nearest BSs summed) of the example urban fix at 20 dB.",
         plots.plot_urban_correlogram)(figure_data.urban_correlogram_payload)

register("fig09_rmse_vs_snr", "Fig. 9",
         "(a) DPE RMSE against SNR for M = 6, 12, 18, 24 nearest BSs: the honest receiver (window centred on a "
         f"{paper.PRIOR_SIGMA_M:g} m "
         "prior, certified search; solid) and the paper's truth-centred grid (dashed); (b) the honest receiver beside the "
         "Cramér–Rao bound (the bounds chapter), log axis.",
         result_plots.plot_rmse_vs_snr)(
    lambda progress=False, trials=None: figure_data.rmse_payload(
        paper.fig9() if trials is None else paper.fig9(honest_trials=trials, truth_trials=trials), progress))

register("fig10_cdf_dpe_vs_otdoa", "Fig. 10",
         "CDF of the position error of DPE and OTDoA with the 4 nearest BSs, SNR per link from the UMi path loss: "
         f"DPE centred on the OTDoA fix or on a {paper.PRIOR_SIGMA_M:g} m prior (certified search) and on the truth "
         "(the paper's set-up); "
         "OTDoA with the first-path and the strongest-peak ToA.", result_plots.plot_cdf)(
    lambda progress=False, trials=None: figure_data.cdf_payload(paper.fig10() if trials is None else paper.fig10(trials), progress))

register("readings_table", None,
         "Which reading of the paper reproduces which of its claims about Figs. 9 and 10: the set-up as this book "
         "reads it (window centred on the truth, RMS delay spread, per-sample SNR, L = 12, first-path OTDoA), one "
         "reading changed at a time, and the honest receiver.", result_plots.plot_readings)(figure_data.readings_payload)
