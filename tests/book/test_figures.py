"""Figure-diff: regenerate every registered figure and compare with the committed baseline.

Each payload comes from ``figures.compute``, which computes it once per state of the code (its cache key hashes the
code of the whole package): in ``make test`` the book's chapters computed most of them minutes earlier, from the same
code.

Data (figures/data/<id>.json): every number within |a - e| <= DATA_ATOL + DATA_RTOL |e|, everything else equal.
Image (figures/<id>.png): matplotlib's compare_images RMS over pixels (0–255 scale) <= IMAGE_RMS_TOL.
On failure the message names the figure and the largest difference, and a diff image is written to
``figure-diff/<id>-failed-diff.png`` in the repository.

The Monte Carlo figures read the engine's store (``dpe5g.simulation.store``) when it holds the experiment for the current code (the
cache key hashes the config and the source of every module the numbers depend on); on a fresh clone the first
build computes it, so ``make test`` there regenerates Fig. 9 from its seed.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from matplotlib.testing.compare import compare_images

from dpe5g.figures import registry as figures
from figure_diff import compare_data


ROOT = Path(__file__).resolve().parents[2]
BASELINE = ROOT / "figures"
DIFF_DIR = ROOT / "figure-diff"

DATA_RTOL = 1e-6  # floating-point results may differ in the last bits between CPUs (SIMD width, FFT plans)
DATA_ATOL = 1e-9
IMAGE_RMS_TOL = 1.0  # same matplotlib + bundled FreeType + DejaVu Sans: identical pixels expected


@pytest.fixture(scope="module")
def regenerated(tmp_path_factory):
    out = tmp_path_factory.mktemp("figures")
    cache = {}

    def get(fig_id):
        if fig_id not in cache:
            cache[fig_id] = figures.write(fig_id, out)
        return cache[fig_id]

    return get


def test_baselines_match_registry():
    committed = {p.stem for p in BASELINE.glob("*.png")}
    committed_data = {p.stem for p in (BASELINE / "data").glob("*.json")}
    assert committed == set(figures.REGISTRY), "figures/*.png and the registry disagree: run `make figures`"
    assert committed_data == set(figures.REGISTRY), "figures/data/*.json and the registry disagree"


@pytest.mark.parametrize("fig_id", list(figures.REGISTRY))
def test_figure_data(fig_id, regenerated):
    _, js = regenerated(fig_id)
    expected = json.loads((BASELINE / "data" / f"{fig_id}.json").read_text())
    actual = json.loads(js.read_text())
    ok, where, diff = compare_data(expected, actual, DATA_RTOL, DATA_ATOL)
    assert ok, f"{fig_id}: data differ from baseline at {where} (largest |difference| {diff:.3g})"


@pytest.mark.parametrize("fig_id", list(figures.REGISTRY))
def test_figure_image(fig_id, regenerated):
    png, _ = regenerated(fig_id)
    result = compare_images(str(BASELINE / f"{fig_id}.png"), str(png), tol=IMAGE_RMS_TOL, in_decorator=True)
    if result is not None:
        DIFF_DIR.mkdir(exist_ok=True)
        diff = Path(result["diff"])
        kept = DIFF_DIR / f"{fig_id}-failed-diff.png"
        if diff.exists():
            shutil.copy(diff, kept)
        shutil.copy(png, DIFF_DIR / f"{fig_id}-actual.png")
        pytest.fail(f"{fig_id}: image RMS difference {result['rms']:.3f} > {IMAGE_RMS_TOL} (diff image: {kept})")


def test_compare_data_catches_a_change():
    payload = figures.compute("fig01_tdl_a")
    changed = json.loads(json.dumps(payload))
    changed["data"]["pdp_db"][3] += 1e-3
    ok, where, diff = compare_data(payload, changed, DATA_RTOL, DATA_ATOL)
    assert not ok and "pdp_db[3]" in where and diff == pytest.approx(1e-3)


# ---------------------------------------------------------------------------------------------------------------
# Readability of the drawn figures (issue 10): drawn from the committed data, so these run in a second.

def _drawn_texts(fig_id, monkeypatch):
    """Render ``fig_id`` from its committed data, draw it as it is saved, and return (fig, renderer, the non-empty
    Text artists actually drawn, each once)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    payload = json.loads((BASELINE / "data" / f"{fig_id}.json").read_text())
    fig = figures.render(payload)
    FigureCanvasAgg(fig)
    drawn = {}
    draw = Text.draw

    def record(self, renderer):
        if self.get_visible() and self.get_text().strip():
            drawn[id(self)] = self
        return draw(self, renderer)

    monkeypatch.setattr(Text, "draw", record)
    fig.canvas.draw()
    monkeypatch.setattr(Text, "draw", draw)
    return fig, fig.canvas.get_renderer(), list(drawn.values())


def _overlap_px(a, b) -> float:
    return min(max(0.0, min(a.x1, b.x1) - max(a.x0, b.x0)), max(0.0, min(a.y1, b.y1) - max(a.y0, b.y0)))


def test_fig07_labels_do_not_overlap(monkeypatch):
    """Fig. 7: no two texts (street names, BS numbers, ticks, labels, legend) overlap, all lie inside the figure,
    and the map's labels inside the map."""
    fig, renderer, texts = _drawn_texts("fig07_deployment_map", monkeypatch)
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in texts]
    assert len(boxes) > 26 + 11  # every BS number and street name is drawn
    frame = fig.bbox
    outside = [s for s, b in boxes if b.x0 < frame.x0 or b.y0 < frame.y0 or b.x1 > frame.x1 or b.y1 > frame.y1]
    assert not outside, f"texts outside the figure: {outside}"
    ax = fig.axes[0]
    area = ax.get_window_extent(renderer)
    cut = [t.get_text() for t in ax.texts
           if not area.contains(*t.get_window_extent(renderer).p0) or not area.contains(*t.get_window_extent(renderer).p1)]
    assert not cut, f"labels cut by the map's border: {cut}"
    overlaps = [(boxes[i][0], boxes[j][0], round(_overlap_px(boxes[i][1], boxes[j][1]), 1))
                for i in range(len(boxes)) for j in range(i + 1, len(boxes))
                if _overlap_px(boxes[i][1], boxes[j][1]) > 0.0]
    assert not overlaps, f"overlapping texts (px): {overlaps}"


@pytest.mark.parametrize("fig_id, axes_index", [("fig06_cost_surface", 0), ("fig08_urban_correlogram", 0), ("fig09_rmse_vs_snr", 1),
                                                 ("fig10_cdf_dpe_vs_otdoa", 0), ("fig10_cdf_dpe_vs_otdoa", 1)])
def test_legend_off_the_data_and_ticks_readable(fig_id, axes_index, monkeypatch):
    """The legend lies outside the data area, and every tick label is at least 9 pt (the book shows the PNGs at about
    their saved width)."""
    fig, renderer, texts = _drawn_texts(fig_id, monkeypatch)
    ax = fig.axes[axes_index]
    legend = ax.get_legend()
    assert legend is not None
    assert _overlap_px(legend.get_window_extent(renderer), ax.get_window_extent(renderer)) == 0.0
    for a in fig.axes:
        for lab in a.get_xticklabels() + a.get_yticklabels():
            if lab.get_text():
                assert lab.get_fontsize() >= 9, (fig_id, lab.get_text(), lab.get_fontsize())


def test_fig09_ticks_and_paper_values(monkeypatch):
    """Fig. 9: our curves on a linear axis labelled every 0.1 m (values read to 0.1 m), the paper's stated 6 m at
    10 dB on a short top panel above an axis break, and the paper's sub-metre line."""
    fig, renderer, texts = _drawn_texts("fig09_rmse_vs_snr", monkeypatch)
    top, ax = fig.axes[0], fig.axes[1]
    lo, hi = ax.get_ylim()
    labelled = [round(t, 6) for t, lab in zip(ax.get_yticks(), ax.get_yticklabels()) if lo <= t <= hi and lab.get_text()]
    assert ax.get_yscale() == "linear" and len(labelled) >= 6 and 1.0 in labelled, labelled
    assert np.allclose(np.diff(labelled), 0.1)
    data = np.concatenate([ln.get_ydata() for ln in ax.get_lines() if ln.get_label().startswith("M = ")])
    assert lo <= data.min() and data.max() <= hi
    assert ax.get_xlabel().startswith("SNR per")
    paper = [ln for ln in top.get_lines() if ln.get_label().startswith("paper (text)")]
    assert any(list(ln.get_xdata()) == [10.0] and list(ln.get_ydata()) == [6.0] for ln in paper)
    assert top.get_ylim()[0] > hi  # the break: the top panel starts above the data panel
    assert any(ln.get_label().startswith("paper (text): sub-metre") for ln in ax.get_lines())


def test_payload_is_computed_once_per_state_of_the_code(tmp_path, monkeypatch):
    """compute stores a payload under a key of the figure, its trial count and the package's code, and reads it back
    instead of computing it again: the stored payload is what a new computation gives, and a different figure or trial
    count has its own entry."""
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path))
    path = figures.payload_path("fig01_tdl_a")
    assert path.parent == tmp_path / "payloads" and not path.exists()
    first = figures.compute("fig01_tdl_a")
    assert path.exists() and figures.load_payload("fig01_tdl_a") == first
    marked = json.loads(json.dumps(first))
    marked["data"]["pdp_db"][0] = 123.0  # a marker: a second compute must return the stored payload
    figures.save_payload("fig01_tdl_a", None, marked)
    assert figures.compute("fig01_tdl_a")["data"]["pdp_db"][0] == 123.0
    others = {figures.payload_path("fig02_tdl_b"), figures.payload_path("fig09_rmse_vs_snr", 50),
              figures.payload_path("fig09_rmse_vs_snr", 60), path}
    assert len(others) == 4
    path.unlink()
    assert figures.compute("fig01_tdl_a") == first


def test_a_figure_that_fails_its_check_leaves_both_files_as_they_were(tmp_path, monkeypatch):
    """figures.write draws and checks the figure before writing either file: a figure too wide for the book's column
    raises, and the PNG and the data JSON already there are untouched (no new data beside an old image)."""
    from matplotlib.figure import Figure

    (tmp_path / "data").mkdir()
    png, js = tmp_path / "fig01_tdl_a.png", tmp_path / "data" / "fig01_tdl_a.json"
    png.write_bytes(b"old png")
    js.write_text("old json")
    monkeypatch.setattr(figures, "render", lambda payload: Figure(figsize=(12, 3)))
    with pytest.raises(ValueError, match="in wide"):
        figures.write("fig01_tdl_a", tmp_path)
    assert png.read_bytes() == b"old png" and js.read_text() == "old json"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["data", "fig01_tdl_a.json", "fig01_tdl_a.png"]
