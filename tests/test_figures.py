"""Figure-diff: regenerate every registered figure from scratch and compare with the committed baseline.

Data (figures/data/<id>.json): every number within |a - e| <= DATA_ATOL + DATA_RTOL |e|, everything else equal.
Image (figures/<id>.png): matplotlib's compare_images RMS over pixels (0–255 scale) <= IMAGE_RMS_TOL.
On failure the message names the figure and the largest difference, and a diff image is written to
``figure-diff/<id>-failed-diff.png`` in the repository.

The Monte Carlo figures read ``dpe5g.montecarlo``'s cache when it holds the experiment for the current code (the
cache key hashes the config and the source of every module the numbers depend on); on a fresh clone the first
build computes it, so ``make test`` there regenerates Fig. 9 from its seed.
"""

import json
import shutil
from pathlib import Path

import pytest
from matplotlib.testing.compare import compare_images

from dpe5g import figures

ROOT = Path(__file__).resolve().parents[1]
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
    ok, where, diff = figures.compare_data(expected, actual, DATA_RTOL, DATA_ATOL)
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
    ok, where, diff = figures.compare_data(payload, changed, DATA_RTOL, DATA_ATOL)
    assert not ok and "pdp_db[3]" in where and diff == pytest.approx(1e-3)
