"""A city of one's own (issue 56): ``dpe5g trace --out DIR`` traces a scene file of the user's with its own settings
into DIR, and ``dpe5g run --channel traced --city DIR`` runs Fig. 9's and Fig. 10's studies on it with every
receiver, through the command line, nothing of the repository's store touched and no module's globals patched."""

import json
import shutil
from pathlib import Path

import pytest

from dpe5g.city import dataset
from dpe5g.cli import main as cli
from dpe5g.common.locations import STORE_DIR

#: a tiny trace: Sionna RT's street-canyon test scene as "a scene file of one's own", 4 BSs, 10 UEs, specular only
TINY = ["--side", "60", "--density", "1000", "--ues", "10", "--samples", "10000", "--max-depth", "2",
        "--scattering", "0"]


@pytest.fixture(scope="module")
def scene_file():
    import sionna.rt as rt

    return rt.scene.simple_street_canyon


def test_trace_a_city_of_ones_own_and_run_the_receivers_on_it(tmp_path, scene_file, monkeypatch, capsys):
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    store_before = {p: p.stat().st_mtime_ns for p in (STORE_DIR / dataset.CITY_FOLDER).iterdir()}
    scene_copy = tmp_path / "scene" / Path(scene_file).name  # (a copy: the test edits it below)
    shutil.copytree(Path(scene_file).parent, scene_copy.parent)
    trace = ["trace", "--out", "own", "--scene", str(scene_copy), *TINY]
    assert cli.main(trace) == 0
    out = capsys.readouterr().out
    assert "links of 10 UEs and 4 BSs traced" in out and "dpe5g run --channel traced --city own" in out
    record = dataset.read_record("mycity", tmp_path / "own")
    assert record["spec"]["scene"] == str(scene_copy) and record["spec"]["n_bs"] == 4 and record["spec"]["n_ue"] == 10
    assert not record["spec"]["diffuse_reflection"]
    assert cli.main(trace) == 0 and "is whole and was traced with these settings" in capsys.readouterr().out
    edited = scene_copy.read_text().replace("<scene version", "<!-- edited -->\n<scene version", 1)
    scene_copy.write_text(edited)  # the same settings, another scene file: traced again
    assert cli.main(trace) == 0 and "links of 10 UEs and 4 BSs traced" in capsys.readouterr().out

    fig10 = ["run", "--channel", "traced", "--city", "own", "--trials", "3", "--snr-mode", "link-budget",
             "--centring", "otdoa", "--otdoa-nlos", "--out", "fig10.csv"]
    assert cli.main(fig10) == 0
    out = capsys.readouterr().out
    assert f"the traced paths of {tmp_path / 'own' / 'cities' / 'mycity_deployment.json'}" in out
    assert "DPE less NLoS-aware OTDoA on the same trials" in out
    cfg = json.loads((tmp_path / "fig10.json").read_text())["experiment"]
    assert cfg["channel"] == "traced" and cfg["otdoa_nlos"]
    assert cli.main(["run", "--channel", "traced", "--city", "own", "--trials", "3", "--snr", "10", "30",
                     "--out", "fig9.csv"]) == 0
    assert "DPE: median / 90 % / RMSE" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in (STORE_DIR / dataset.CITY_FOLDER).iterdir()} == store_before


BAD = [
    (["trace", "--density", "200"], "--density: a city of your own needs --out DIR"),
    (["trace", "--out", "own", "--scene", "nothere.xml"], "nothere.xml: no such Mitsuba XML scene file"),
    (["trace", "--out", "own", "--scene", "paris"], "scene must be one of munich, etoile, florence, san_francisco"),
    (["trace", "--out", str(STORE_DIR / "mine")], "is in the results store"),
    (["trace", "--out", "own", "--density", "1"], "places 0 BSs: n_bs must be an integer in [3, 200]"),
    (["trace", "--out", "own", "--name", "../x"], "--name must be a name"),
    (["trace", "--out", "own", "--name", "x_deployment"], "--name must not end in _deployment or _view"),
    (["trace", "--out", "own", "--side", "inf"], "--side must be in [50, 2000] m"),
    (["trace", "--out", "own", "--side", "1e200"], "--side must be in [50, 2000] m"),
    (["trace", "--out", "own", "--scattering", "1.5"], "scattering_coefficient"),
    (["run", "--trials", "2", "--channel", "traced", "--out", "r.csv"], "--channel traced needs --city"),
    (["run", "--trials", "2", "--city", "own", "--out", "r.csv"], "--city applies to --channel traced"),
    (["run", "--trials", "2", "--channel", "traced", "--city", "empty", "--out", "r.csv"],
     "--city empty: cities/ in it holds 0 traced cities"),
    (["run", "--trials", "2", "--channel", "traced", "--city", "munich", "--deployment", "tst", "--out", "r.csv"],
     "--deployment does not apply to --channel traced"),
    (["run", "--trials", "2", "--channel", "traced", "--city", "munich", "--reuse", "6", "--out", "r.csv"],
     "channel 'traced' takes LoS and every delay from the traced paths"),
]


@pytest.mark.parametrize("argv, needle", BAD)
def test_bad_own_city_input_is_one_line(tmp_path, monkeypatch, capsys, argv, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
