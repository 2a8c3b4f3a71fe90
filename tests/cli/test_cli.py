"""The command line: bad input is one line on stderr naming the parameter and exit code 2; ``dpe5g run`` writes its
tidy results; ``dpe5g figures`` writes the committed baselines only with ``--update-baselines``."""

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dpe5g.receivers import search_config
from dpe5g.simulation import chunk_cache, experiment
from dpe5g.studies import catalog, paper
from dpe5g.cli import main as cli

ROOT = cli.BASELINE_DIR.parent

#: a valid deployment of 4 BSs (CSV), and files that are not
FILES = {
    "four.csv": "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,24\nC,0,100,10,24\nD,100,100,10,24\n",
    "watts.csv": "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,0.25\nC,0,100,10,24\n",
    "tall.csv": "id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,24\nC,0,100,10000,24\n",
    "trunc.json": '{"base_stations": [',
    "list.json": "[1, 2, 3]",
    "layout.txt": "x y\n",
    "existing.csv": "keep me\n",
    "existing2.json": "keep me, the provenance of existing2.csv\n",
    "afile": "not a folder\n",
    "existing.html": "keep me too\n",
}
_BS4 = [{"x_m": 50.0 * i, "y_m": 40.0 * (i % 2), "height_m": 10, "power_dbm": 24} for i in range(4)]
_REGION = {"x_min_m": -10, "y_min_m": -10, "x_max_m": 200, "y_max_m": 100}
#: JSON deployments with a wrong type, key or geometry (issue 33), each written as <name>.json
BAD_JSON = {
    "bld5": {"base_stations": _BS4, "region": _REGION, "buildings": 5},
    "anchorhere": {"base_stations": _BS4, "region": _REGION, "anchor": "here"},
    "streets7": {"base_stations": _BS4, "region": _REGION, "streets": 7},
    "stations": {"stations": _BS4, "region": _REGION},
    "boolx": {"base_stations": [{**_BS4[0], "x_m": True}] + _BS4[1:], "region": _REGION},
    "textx": {"base_stations": [{**_BS4[0], "x_m": "0"}] + _BS4[1:], "region": _REGION},
    "line": {"base_stations": [{**b, "y_m": 0.0} for b in _BS4], "region": _REGION},
    "region5": {"base_stations": _BS4, "region": 5},
}
TABLE_COLUMNS = ["trial", "snr_db", "m", "error_m", "est_x_m", "est_y_m", "true_x_m", "true_y_m", "n_los", "edge",
                 "certified"]
RUN = ("run", "--trials", "2", "--out", "r.csv")


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A temporary working directory holding ``FILES``, a folder ``adir`` and a folder named like a file,
    ``folder.json``; the Monte Carlo cache inside it."""
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "notutf.json").write_bytes(b"\xff\xfe\x00{")
    (tmp_path / "adir").mkdir()
    (tmp_path / "folder.json").mkdir()
    (tmp_path / "folder.csv").mkdir()
    (tmp_path / "folder.html").mkdir()
    for name, doc in BAD_JSON.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(doc))
    (tmp_path / "deep.json").write_text("[" * 200_000)
    (tmp_path / "extra.csv").write_text(FILES["four.csv"].replace("B,100,0,10,24", "B,100,0,10,24,9"))
    (tmp_path / "many.csv").write_text("id,x_m,y_m,height_m,power_dbm\n" + "".join(
        f"B{i},{i % 200 * 7.0},{i // 200 * 7.0},10,24\n" for i in range(40_000)))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path / "cache"))
    return tmp_path


BAD = [
    # trace on a cluster: chunk size and workers, checked even where the city is current and nothing is traced
    (("trace", "--chunk-batches", "0"), "--chunk-batches must be an integer in [1, 10000]"),
    (("trace", "--workers", "0"), "--workers must be an integer in [1, 256]"),
    # profile: delay spread sign, units and range, profile name, K-factor
    (("profile", "C", "--delay-spread", "-65e-9"), "--delay-spread: delay_spread_s=-6.5e-08 s is outside"),
    (("profile", "C", "--delay-spread=-65e-9"), "delay_spread_s=-6.5e-08 s"),
    (("profile", "C", "--delay-spread", "1e-3"), "delay_spread_s=0.001 s is outside the allowed range"),
    (("profile", "C", "--delay-spread", "65"), "looks like nanoseconds"),
    (("profile", "C", "--delay-spread", "nan"), "delay_spread_s must be finite"),
    (("profile", "C", "--delay-spread", "-inf"), "delay_spread_s must be finite"),
    (("profile", "C", "--delay-spread", "65ns"), "argument --delay-spread: invalid float value"),
    (("profile", "Z"), "profile must be one of"),
    (("profile", "D", "--k-factor-db", "inf"), "--k-factor-db"),
    (("profile",), "required: name"),
    (("bogus",), "argument command: invalid choice"),
    # figures: ids, trials, where it may write
    (("figures", "--only", "fig99_nothing", "--out", "o"), "figure must be one of"),
    (("figures", "--only"), "argument --only: expected at least one argument"),
    (("figures",), "--out DIR is required"),
    (("figures", "--trials", "5"), "--out DIR is required"),
    (("figures", "--update-baselines", "--trials", "5"), "--trials 5 cannot be used with --update-baselines"),
    (("figures", "--update-baselines", "--out", "o"), "--out o cannot be used with --update-baselines"),
    (("figures", "--out", "{baselines}"), "is in the committed baselines folder"),
    (("figures", "--out", "{baselines}/data"), "is in the committed baselines folder"),
    (("figures", "--out", "afile"), "--out afile: afile exists and is not a folder"),
    (("figures", "--only", "fig01_tdl_a", "--trials", "5", "--out", "o"), "--trials applies to"),
    (("figures", "--only", "fig09_rmse_vs_snr", "--trials", "0", "--out", "o"), "--trials must be"),
    # scene: the output file
    (("scene", "--out", "folder.html"), "--out folder.html: is a folder"),
    (("scene", "--out", "/proc/x.html"), "--out /proc/x.html: cannot write in /proc"),
    (("scene", "--out", "afile/x.html"), "--out afile/x.html: afile exists and is not a folder"),
    (("scene", "--out", "scene.png"), "--out scene.png: must end in .html or .htm"),
    (("scene", "--out", "s.html", "--deployment", "missing.csv"), "--deployment: deployment file missing.csv"),
    (("scene", "--out", "s.html", "--deployment", "line.json"), "--deployment: deployment file line.json: the 4 base stations lie on"),
    # deployment files
    (("deployment", "missing.json"), "deployment file missing.json does not exist"),
    (("deployment", "adir"), "deployment file adir is not a file"),
    (("deployment", "trunc.json"), "trunc.json: is not valid JSON"),
    (("deployment", "notutf.json"), "notutf.json: is not valid JSON"),
    (("deployment", "list.json"), "must hold a JSON object"),
    (("deployment", "layout.txt"), "must end in .json or .csv"),
    (("deployment", "watts.csv"), "base station 2 (B): power_dbm must be in [10, 60] dBm"),
    (("deployment", "tall.csv"), "height_m must be in [1.5, 150] m"),
    (("deployment", "bld5.json"), "bld5.json: buildings must be a list of objects, got int"),
    (("deployment", "anchorhere.json"), "anchorhere.json: anchor must be an object {lat_deg, lon_deg}"),
    (("deployment", "streets7.json"), "streets7.json: streets must be a list"),
    (("deployment", "stations.json"), "stations.json: missing base_stations (it has 'stations', 'region')"),
    (("deployment", "boolx.json"), "base station 1: x_m must be a number in [-100000, 100000] m, got True"),
    (("deployment", "textx.json"), "base station 1: x_m must be a number in [-100000, 100000] m, got '0'"),
    (("deployment", "line.json"), "the 4 base stations lie on one line"),
    (("deployment", "region5.json"), "region5.json: needs a region {x_min_m, y_min_m, x_max_m, y_max_m}"),
    (("deployment", "deep.json"), "deep.json: is nested too deeply to be a deployment"),
    (("deployment", "extra.csv"), "extra.csv: row 3 has more fields than the header"),
    (("deployment", "many.csv"), "many.csv: holds 40000 base stations; at most 4096 are read (one PRS ID each)"),
    (RUN + ("--deployment", "bld5.json"), "bld5.json: buildings must be a list of objects, got int"),
    (("profile", "C", "--delay-spread", "1e-300"), "delay_spread_s=1e-300 s is outside the allowed range [1e-09"),
    (("scene", "--out", "existing.html"), "--out existing.html: exists; pass --force"),
    (("scene", "--out", "s" * 300 + ".html"), "--out: the file name is 305 bytes long; at most 200"),
    (RUN[:-1] + ("r" * 300 + ".csv",), "--out: the file name is 304 bytes long; at most 200"),
    (RUN + ("--centring", "truth", "--prior-sigma", "-5"), "--prior-sigma applies to --centring prior only"),
    (RUN + ("--centring", "otdoa", "--prior-sigma", "5"), "--prior-sigma applies to --centring prior only"),
    (RUN + ("--prior-sigma", "0"), "--prior-sigma must be in (0, 1000] m, got 0.0"),
    (RUN + ("--prior-sigma", "-5"), "--prior-sigma must be in (0, 1000] m, got -5.0"),
    (RUN + ("--snr", "10", "10"), "--snr: snrs_db must not repeat an SNR"),
    (RUN + ("--m", "6", "6"), "--m: m_values must be a non-empty increasing tuple"),
    (RUN + ("--m", "12", "6"), "--m: m_values must be a non-empty increasing tuple"),
    (RUN + ("--reuse", "6", "--centring", "truth"), "--reuse 6 needs the honest receiver's certified search: use "
                                                    "--centring prior or --centring otdoa"),
    # run: every parameter
    (("run",), "required: --trials, --out"),
    (("run", "--trials", "x", "--out", "r.csv"), "argument --trials: invalid int value"),
    (("run", "--trials", "0", "--out", "r.csv"), "--trials: n_trials must be an integer"),
    (("run", "--trials", "2", "--out", "r.txt"), "--out r.txt: must end in .csv"),
    (("run", "--trials", "2", "--out", "r.json"), "--out r.json: must end in .csv"),
    (("run", "--trials", "2", "--out", "existing2.csv"), "--out existing2.csv: existing2.json beside it (where its "
                                                          "provenance goes) exists; pass --force"),
    (("run", "--trials", "2", "--out", "existing.csv"), "--out existing.csv: exists; pass --force"),
    (("run", "--trials", "2", "--out", "folder.csv", "--force"), "--out folder.csv: is a folder"),
    (("run", "--trials", "2", "--out", "/proc/r.csv"), "--out /proc/r.csv: cannot write in /proc"),
    (RUN + ("--snr",), "argument --snr: expected at least one argument"),
    (RUN + ("--snr", "nan"), "--snr: snr_db must be finite"),
    (RUN + ("--snr", "10", "inf"), "--snr: snr_db must be finite"),
    (RUN + ("--snr", "-1e3"), "--snr: snr_db must be in [-50, 100] dB"),
    (RUN + ("--m", "27"), "--m: m_values must not exceed the deployment's 26 base stations"),
    (RUN + ("--m", "2", "6"), "--m: m_values entry must be an integer in [3,"),
    (RUN + ("--m", "6", "--deployment", "four.csv"), "--m: m_values must not exceed the deployment's 4"),
    (RUN + ("--taps", "0"), "--taps: n_taps must be an integer in [1, 4096]"),
    (RUN + ("--otdoa-nlos",), "--otdoa-nlos runs the NLoS-aware OTDoA on the OTDoA receiver's ToAs: use --centring otdoa"),
    (RUN + ("--dpe-nlos", "--centring", "truth"), "--dpe-nlos searches the certified window of an honest receiver"),
    (RUN + ("--nlos-excess", "InH"), "--nlos-excess must be one of none, UMi, UMa, RMa, SMa; got 'InH'"),
    (RUN + ("--los-mode", "half"), "--los-mode: los_mode must be one of"),
    (RUN + ("--nlos-excess", "UMi", "--reuse", "6"), "--nlos-excess: nlos_excess_median_s > 0 is not modelled with"),
    (RUN + ("--taps", "4097"), "--taps: n_taps must be an integer in [1, 4096]"),
    (RUN + ("--centring", "oracle"), "--centring: centring must be one of truth, prior, otdoa"),
    (RUN + ("--delay-spread", "65"), "--delay-spread: delay_spread_s=65 s is outside"),
    (RUN + ("--delay-spread", "-65e-9"), "--delay-spread: delay_spread_s=-6.5e-08 s is outside"),
    (RUN + ("--prior-sigma", "nan"), "--prior-sigma must be in (0, 1000] m, got nan"),
    (RUN + ("--seed", "-1"), "--seed: seed must be an integer"),
    (RUN + ("--reuse", "5"), "--reuse: prs_reuse must be one of 0, 2, 4, 6, 12"),
    (RUN + ("--snr-mode", "budget"), "--snr-mode must be one of fixed, link-budget; got 'budget'"),
    (RUN + ("--snr-mode", "link-budget", "--snr", "20"), "--snr does not apply to --snr-mode link-budget"),
    (RUN + ("--deployment", "watts.csv"), "--deployment: deployment file"),
    (RUN + ("--deployment", "missing.csv"), "--deployment: deployment file"),
]


@pytest.mark.parametrize("args, needle", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_input_is_one_line_naming_the_parameter_exit_2(args, needle, workdir, capsys):
    args = [a.format(baselines=cli.BASELINE_DIR) for a in args]
    before = sorted(p.name for p in workdir.iterdir())
    assert cli.main(args) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], err
    assert lines[0].startswith("dpe5g"), err
    assert sorted(p.name for p in workdir.iterdir()) == before  # nothing written
    assert (workdir / "existing.csv").read_text() == FILES["existing.csv"]
    assert (workdir / "existing2.json").read_text() == FILES["existing2.json"]
    assert (workdir / "existing.html").read_text() == FILES["existing.html"]


def test_enough_distinct_bad_inputs():
    assert len({a for a, _ in BAD}) >= 75


def sub(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "dpe5g", *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd)


@pytest.mark.parametrize("args", [
    ("profile", "C", "--delay-spread", "-65e-9"),
    ("deployment", "watts.csv"),
    ("scene", "--out", "/proc/x.html"),
    ("figures", "--out", "afile"),
    ("run", "--trials", "1", "--out", "existing.csv"),
])
def test_no_traceback_in_a_subprocess(args, workdir):
    r = sub(*args, cwd=workdir)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_bad_xla_level_is_one_line_from_the_command_line(workdir):
    """DPE5G_XLA_OPT_LEVEL is read when dpe5g is imported, before the CLI's handler exists: the command line must
    still report it in one line with exit code 2, and importing the library must still raise."""
    env = {**os.environ, "DPE5G_XLA_OPT_LEVEL": "7"}
    msg = "DPE5G_XLA_OPT_LEVEL must be one of 0, 1, 2, 3 or xla, got '7'"
    r = subprocess.run([sys.executable, "-m", "dpe5g", "profile", "C"], capture_output=True, text=True, timeout=300,
                       cwd=workdir, env=env)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [f"dpe5g: error: {msg}"], r.stderr
    r = subprocess.run([sys.executable, "-c", "import dpe5g"], capture_output=True, text=True, timeout=300,
                       cwd=workdir, env=env)
    assert r.returncode == 1 and f"ValueError: {msg}" in r.stderr, r.stderr


def test_deployment_summary():
    r = sub("deployment")
    assert r.returncode == 0 and "26 BSs" in r.stdout and "227,360 m2" in r.stdout


def test_profile_prints_table(capsys):
    assert cli.main(["profile", "D"]) == 0
    out = capsys.readouterr().out
    assert "TDL-D" in out and "K = 13.3 dB" in out
    assert cli.main(["profile", "C"]) == 0
    out = capsys.readouterr().out
    assert "TDL-C" in out and "K =" not in out and "None" not in out  # an NLoS profile has no K-factor


def test_a_reader_that_leaves_ends_the_output_quietly():
    """`dpe5g profile D | head -1`: the reader closes the pipe early (here `true`, which reads nothing, so the first
    write already fails): no "error: Broken pipe", no traceback, exit 141 as a Unix tool killed by SIGPIPE."""
    r = subprocess.run(["bash", "-c", f"{sys.executable} -m dpe5g profile D | true; echo ${{PIPESTATUS[0]}}"],
                       capture_output=True, text=True, timeout=120)
    assert r.stdout.strip() == "141" and r.stderr == "", r.stderr


def test_run_help(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["run", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    for option in ("--trials", "--out", "--force", "--deployment", "--snr", "--m", "--taps", "--delay-spread",
                   "--centring", "--prior-sigma", "--seed"):
        assert option in out


def test_run_defaults_are_the_papers_experiments():
    """With the defaults and the paper's trial counts, ``dpe5g run`` is Fig. 9's experiment (and reuses its cache);
    anything else is its own experiment."""
    parse = cli.build_parser().parse_args
    assert cli.run_experiment(parse(["run", "--trials", "400", "--out", "x.csv"])) == paper.fig9_honest(400)
    truth = parse(["run", "--trials", "7", "--out", "x.csv", "--centring", "truth"])
    assert cli.run_experiment(truth) == paper.fig9_truth(7)
    mine = cli.run_experiment(parse(["run", "--trials", "7", "--out", "x.csv", "--m", "6", "12", "--taps", "4",
                                     "--delay-spread", "1e-7", "--seed", "3"]))
    assert mine.run.name == "run" and mine.receiver.m_values == (6, 12) and mine.receiver.search.n_taps == 4
    assert mine.run.seed == 3 and mine.receiver.search.method == "bnb"
    assert mine.receiver.prior_scale_m == paper.PRIOR_SIGMA_M
    assert mine.scenario.delay_spread_s == 1e-7


def read_csv(path):
    """The rows of a results CSV, read with the csv module's defaults (``Results.write_csv``)."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def csv_config(path) -> dict:
    """The experiment's settings from the sidecar JSON beside a results CSV (``Results.write_provenance``)."""
    return json.loads(Path(path).with_suffix(".json").read_text())["experiment"]


def test_run_writes_csv_and_its_provenance_and_refuses_to_overwrite(workdir, capsys):
    args = ["run", "--trials", "2", "--snr", "10", "30", "--m", "6", "--centring", "truth"]
    assert cli.main(args + ["--out", "r.csv"]) == 0
    out = capsys.readouterr().out
    assert "DPE: median / 90 % / RMSE of the error (m)" in out and "M = 6" in out and "wrote r.csv (4 rows" in out and "r.json" in out
    rows = read_csv(workdir / "r.csv")
    links = [f"link{k}_{q}" for k in range(1, 7) for q in ("los", "snr_db", "sinr_db")]
    assert list(rows[0]) == TABLE_COLUMNS + links
    assert len(rows) == 2 * 2 * 1
    assert {(r["trial"], r["snr_db"], r["m"]) for r in rows} == {(t, s, "6") for t in "01" for s in ("10.0", "30.0")}
    assert all(float(r["link1_snr_db"]) == float(r["snr_db"]) and r["link6_los"] in ("0", "1") for r in rows)
    assert all(sum(int(r[f"link{k}_los"]) for k in range(1, 7)) == int(r["n_los"]) for r in rows)
    doc = json.loads((workdir / "r.json").read_text())  # the file beside it says what produced it
    cfg = doc["experiment"]
    assert cfg["seed"] == paper.URBAN_SEED and cfg["n_trials"] == 2 and cfg["snrs_db"] == [10.0, 30.0]
    assert cfg["centring"] == "truth" and cfg["m_values"] == [6]
    assert set(doc["columns"]) == set(rows[0]) and all(doc["columns"].values())
    assert doc["provenance"]["dpe5g"] and "commit" in doc["provenance"]
    capsys.readouterr()

    before = (workdir / "r.csv").read_bytes()
    assert cli.main(args + ["--out", "r.csv"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out r.csv: exists; pass --force" in err
    assert cli.main(args + ["--out", "r.csv", "--force"]) == 0
    assert (workdir / "r.csv").read_bytes() == before  # same seed, same results
    assert not list(workdir.glob(".r.*"))  # no temporary file left


def test_run_otdoa_centring_on_a_users_deployment(workdir, capsys):
    """Centring on the OTDoA fix (the honest certified search) on a 4-BS CSV deployment."""
    assert cli.main(["run", "--trials", "1", "--snr", "20", "--m", "4", "--centring", "otdoa",
                     "--deployment", "four.csv", "--out", "sub/o.csv"]) == 0
    out = capsys.readouterr().out
    assert "OTDoA (first_path ToA): median / 90 % / RMSE of the error (m)" in out and "certified:" in out
    assert "DPE less OTDoA (first_path ToA) on the same trials, m (95 % paired interval):" in out
    cfg = csv_config(workdir / "sub" / "o.csv")
    assert cfg["deployment"] == str(workdir / "four.csv")
    assert cfg["otdoa"] is True and cfg["search"]["method"] == "bnb"
    (row,) = read_csv(workdir / "sub" / "o.csv")
    assert set(TABLE_COLUMNS) < set(row) and "otdoa_first_path_error_m" in row and row["m"] == "4"


def test_scene_of_a_users_deployment(workdir, monkeypatch, capsys):
    """``dpe5g scene --deployment FILE``: the 3-D scene of the user's 4-BS deployment (its BSs, the example UE's
    links to all 4, the correlogram of its fix), not ours."""
    from dpe5g.figures import scene3d

    real, drawn = scene3d.export, []
    monkeypatch.setattr(scene3d, "export", lambda p7, p8, *a, **kw: drawn.append((p7, p8)) or real(p7, p8, *a, **kw))
    assert cli.main(["scene", "--deployment", "four.csv", "--out", "s.html"]) == 0
    assert "wrote s.html" in capsys.readouterr().out
    (p7, p8), = drawn
    assert p7["data"]["bs_ids"] == ["A", "B", "C", "D"] and p7["config"]["m"] == 4 and p8["config"]["m"] == 4
    assert (workdir / "s.html").read_text().startswith("<!DOCTYPE html>")


def test_run_m_defaults_to_what_the_deployment_holds():
    assert cli.default_m_values(26) == (6, 12, 18, 24)
    assert cli.default_m_values(24) == (6, 12, 18, 24)
    assert cli.default_m_values(8) == (6, 8)
    assert cli.default_m_values(12) == (6, 12)
    assert cli.default_m_values(4) == (4,)
    assert cli.default_m_values(26, "link_budget") == (4,) and cli.default_m_values(3, "link_budget") == (3,)


def test_run_link_budget_uses_the_deployments_powers(workdir, capsys):
    """--snr-mode link-budget: Fig. 10's set-up on a user's deployment, each link's SNR from its BS's power_dbm
    (the same deployment 36 dB stronger: every link's SNR 36 dB higher), one row per trial."""
    strong = FILES["four.csv"].replace(",24\n", ",60\n")
    assert strong.count(",60\n") == 4
    (workdir / "strong.csv").write_text(strong)
    runs = {}
    for name in ("four", "strong"):
        assert cli.main(["run", "--trials", "2", "--snr-mode", "link-budget", "--deployment", f"{name}.csv",
                         "--out", f"{name}_lb.csv"]) == 0
        runs[name] = read_csv(workdir / f"{name}_lb.csv")
    out = capsys.readouterr().out
    assert "link budget" in out
    assert [r["m"] for r in runs["four"]] == ["4", "4"] and {r["snr_db"] for r in runs["four"]} == {"link_budget"}
    for weak, strong in zip(runs["four"], runs["strong"]):
        for k in range(1, 5):
            assert float(strong[f"link{k}_snr_db"]) - float(weak[f"link{k}_snr_db"]) == pytest.approx(36.0, abs=0.02)
    assert csv_config(workdir / "four_lb.csv")["snr_mode"] == "link_budget"


def test_figures_out_writes_there(tmp_path, capsys):
    assert cli.main(["figures", "--only", "fig01_tdl_a", "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o" / "fig01_tdl_a.png").is_file()
    assert (tmp_path / "o" / "data" / "fig01_tdl_a.json").is_file()


def test_figures_update_baselines(tmp_path, monkeypatch, capsys):
    """--update-baselines writes the baselines folder (here a stand-in in tmp_path), and only it may."""
    base = tmp_path / "figures"
    monkeypatch.setattr(cli, "BASELINE_DIR", base)
    assert cli.main(["figures", "--update-baselines", "--only", "fig01_tdl_a"]) == 2  # no such folder
    assert "no committed baselines folder" in capsys.readouterr().err
    base.mkdir()
    assert cli.main(["figures", "--update-baselines", "--only", "fig01_tdl_a"]) == 0
    assert (base / "fig01_tdl_a.png").is_file() and (base / "data" / "fig01_tdl_a.json").is_file()
    for out in (base, base / "data", tmp_path / "x" / ".." / "figures"):
        assert cli.main(["figures", "--only", "fig02_tdl_b", "--out", str(out)]) == 2
        assert "committed baselines folder" in capsys.readouterr().err
    assert not (base / "fig02_tdl_b.png").exists()


def test_the_real_baselines_are_not_touched_by_a_refusal(capsys):
    stamp = {p: p.stat().st_mtime_ns for p in cli.BASELINE_DIR.rglob("*")}
    for args in (["figures", "--only", "fig01_tdl_a", "--out", str(cli.BASELINE_DIR)],
                 ["figures", "--only", "fig01_tdl_a", "--out", os.path.relpath(cli.BASELINE_DIR)]):
        assert cli.main(args) == 2
    assert {p: p.stat().st_mtime_ns for p in cli.BASELINE_DIR.rglob("*")} == stamp


def test_warm_fills_the_cache_with_the_books_runs(workdir, monkeypatch, capsys):
    tiny = [experiment.Experiment.build(name=f"warm{i}", n_trials=4, chunk_trials=2, seed=i, snrs_db=(20.0,), m_values=(4,),
                                  search=search_config.SearchConfig(half_width_m=2.0, bias_half_width_m=2.0)) for i in (1, 2)]
    monkeypatch.setattr(catalog, "store_experiments", lambda: tiny)
    assert cli.main(["warm"]) == 0
    out = capsys.readouterr().out
    assert out.index("warm2") < out.index("warm1") and "warm: 2 experiments" in out  # the last one first
    for e in tiny:
        assert len(list(chunk_cache.cache_dir(e).glob("trials-*.npz"))) == 2


def test_a_concurrent_writer_of_the_same_out_is_refused_never_replaced(workdir, monkeypatch, capsys):
    """Two runs with one --out: both pass the "exists" check before computing; the one that finishes second fails
    with one line (exit 2) and the first one's file stays, byte for byte, with no temporary file left."""
    from dpe5g.simulation import engine

    real = engine.run

    def first_run_finishes_meanwhile(e, **kw):
        res = real(e, **kw)
        (workdir / "r.csv").write_text("the other run's results\n")
        return res

    monkeypatch.setattr(engine, "run", first_run_finishes_meanwhile)
    assert cli.main(["run", "--trials", "1", "--snr", "20", "--m", "6", "--centring", "truth", "--out", "r.csv"]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if not ln.startswith("run trials")]  # (tqdm)
    assert len(err) == 1 and "--out r.csv: another run wrote it meanwhile" in err[0], err
    assert (workdir / "r.csv").read_text() == "the other run's results\n"
    assert not list(workdir.glob(".r.csv.*"))


def test_output_files_get_the_mode_the_umask_gives(workdir, capsys):
    """Not mkstemp's 0600: a new --out gets 0666 less the umask, and --force on an existing file too."""
    args = ["run", "--trials", "1", "--snr", "20", "--m", "6", "--centring", "truth", "--out", "r.csv"]
    old = os.umask(0o027)
    try:
        assert cli.main(args) == 0
        assert {(workdir / f).stat().st_mode & 0o777 for f in ("r.csv", "r.json")} == {0o640}
        os.umask(0o022)
        assert cli.main(args + ["--force"]) == 0
        assert {(workdir / f).stat().st_mode & 0o777 for f in ("r.csv", "r.json")} == {0o644}
    finally:
        os.umask(old)


def test_ctrl_c_is_one_line_and_exit_130_at_any_moment(workdir):
    """SIGINT while the command line starts (importing JAX, a second or two) and in the middle of a run (once its
    first chunk of trials is cached): one line on stderr, exit 130, no traceback, no --out file; the same command
    then resumes from the cache (the chunks written before the interrupt are not computed again) and writes it.
    (The interpreter's own start-up, before dpe5g's first line runs, is Python's: a few tens of ms.)"""
    import signal
    import time

    args = [sys.executable, "-m", "dpe5g", "run", "--trials", "400", "--snr", "20", "--m", "6", "--centring",
            "truth", "--out", "r.csv"]
    chunks = lambda: sorted((workdir / "cache").glob("run-*/trials-*.npz"))

    def importing_jax(p):  # its shared libraries are mapped: dpe5g's own code is running (its handler is set)
        try:
            return "jaxlib" in Path(f"/proc/{p.pid}/maps").read_text()
        except OSError:
            return False

    for started in (importing_jax, lambda p: bool(chunks())):  # while starting; after the first chunk
        p = subprocess.Popen(args, cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        t0 = time.monotonic()
        while not started(p) and p.poll() is None and time.monotonic() - t0 < 300:
            time.sleep(0.005)
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=300)
        lines = [ln for ln in err.splitlines() if ln.strip() and ("trials" not in ln or "interrupted" in ln)]
        assert p.returncode == 130 and "Traceback" not in err, err  # (not tqdm's bar)
        assert len(lines) == 1 and "interrupted" in lines[0], err
        assert not (workdir / "r.csv").exists() and not list(workdir.glob(".r.csv.*"))
    done = {c.name: c.stat().st_mtime_ns for c in chunks()}
    assert 0 < len(done) < 4
    r = subprocess.run(args, cwd=workdir, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and (workdir / "r.csv").exists(), r.stderr
    assert all(c.stat().st_mtime_ns == done[c.name] for c in chunks() if c.name in done)  # resumed, not redone


def test_sigterm_is_one_line_and_exit_143_like_ctrl_c(workdir):
    """SIGTERM (a job scheduler's stop, `kill`) in the middle of a run: as Ctrl-C, one line, exit 143, no --out file
    and no temporary file (the resume from the cached chunks is the Ctrl-C test's)."""
    import signal
    import time

    args = [sys.executable, "-m", "dpe5g", "run", "--trials", "400", "--snr", "20", "--m", "6", "--centring",
            "truth", "--out", "r.csv"]
    chunks = lambda: sorted((workdir / "cache").glob("run-*/trials-*.npz"))
    p = subprocess.Popen(args, cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    while not chunks() and p.poll() is None and time.monotonic() - t0 < 300:
        time.sleep(0.005)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=300)
    lines = [ln for ln in err.splitlines() if ln.strip() and ("trials" not in ln or "terminated" in ln)]
    assert p.returncode == 143 and "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("dpe5g run: terminated"), err
    assert not (workdir / "r.csv").exists() and not list(workdir.rglob("*.tmp"))


def test_output_does_not_depend_on_the_terminals_encoding(workdir):
    """An ASCII terminal (PYTHONIOENCODING=ascii) once failed on the first σ, after the results were written: the
    command line writes UTF-8 whatever the terminal's encoding."""
    env = {**os.environ, "PYTHONIOENCODING": "ascii", "LC_ALL": "C"}
    r = subprocess.run([sys.executable, "-m", "dpe5g", "run", "--help"], cwd=workdir, env=env, capture_output=True,
                       timeout=120)
    assert r.returncode == 0 and "σ per axis".encode() in r.stdout, r.stderr.decode(errors="replace")
    utf8 = subprocess.run([sys.executable, "-m", "dpe5g", "run", "--help"], cwd=workdir, capture_output=True,
                          timeout=120, env={**os.environ, "PYTHONIOENCODING": "utf-8"})
    assert r.stdout == utf8.stdout


def test_a_cache_that_is_not_a_folder_is_named(workdir, monkeypatch, capsys):
    """DPE5G_CACHE pointing at a file: one line naming the variable, exit 2, no result file."""
    monkeypatch.setenv("DPE5G_CACHE", str(workdir / "afile"))
    assert cli.main(["run", "--trials", "1", "--snr", "20", "--m", "6", "--centring", "truth", "--out", "r.csv"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"DPE5G_CACHE={workdir / 'afile'}: cannot write there" in err[0], err
    assert not (workdir / "r.csv").exists() and (workdir / "afile").read_text() == FILES["afile"]


def test_help_describes_the_command_line(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = " ".join(capsys.readouterr().out.split())  # (argparse wraps the text to the terminal)
    assert "The command line of dpe5g" in out and "exit code 2" in out and "UsageError" not in out


def test_the_deployment_format_is_where_the_user_looks(workdir, capsys):
    """``dpe5g deployment --help`` gives the format and an example in each format; ``--example`` prints them; the
    two examples read as the same BSs and region; power_dbm is optional (a line says what is assumed), and a CSV
    without region columns says how its region was inferred."""
    from dpe5g.phy import deployment

    with pytest.raises(SystemExit):
        cli.main(["deployment", "--help"])
    text = capsys.readouterr().out
    assert all(k in text for k in ("x_m", "height_m", "power_dbm", "region_x_min_m", '"base_stations"', "A,0,0,10,24"))
    deps = {}
    for fmt in ("json", "csv"):
        assert cli.main(["deployment", "--example", fmt]) == 0
        (workdir / f"mine.{fmt}").write_text(capsys.readouterr().out)
        deps[fmt] = deployment.load_deployment(workdir / f"mine.{fmt}")
        assert deps[fmt].assumed == ()
    j, c = deps["json"], deps["csv"]
    assert j.bs_ids == c.bs_ids and j.region == c.region and np.array_equal(j.bs_xyz, c.bs_xyz)
    assert np.array_equal(j.power_dbm, c.power_dbm)
    (workdir / "bare.csv").write_text("x_m,y_m,height_m\n0,0,10\n100,0,10\n0,100,10\n")
    assert cli.main(["deployment", "bare.csv"]) == 0
    out = capsys.readouterr().out
    assert "power_dbm not given for 3 of 3 BSs (BS01, BS02, BS03): 24 dBm" in out
    assert "region not given (columns region_x_min_m" in out and "(-10.0, -10.0, 110.0, 110.0) m" in out
    assert np.all(deployment.load_deployment(workdir / "bare.csv").power_dbm == deployment.DEFAULT_POWER_DBM)
    (workdir / "two.csv").write_text(FILES["four.csv"].replace("power_dbm\n", "power_dbm,region_x_min_m,"
                                                               "region_y_min_m,region_x_max_m,region_y_max_m\n")
                                     .replace("A,0,0,10,24", "A,0,0,10,24,-5,-5,105,105")
                                     .replace("B,100,0,10,24", "B,100,0,10,24,-5,-5,110,105"))
    assert cli.main(["deployment", "two.csv"]) == 2
    assert "region columns region_x_min_m, region_y_min_m, region_x_max_m, region_y_max_m differ" in \
        capsys.readouterr().err


def test_json_and_csv_of_one_deployment_give_one_study(workdir, capsys):
    """The two examples of ``dpe5g deployment --example`` (the same BSs and region): the same errors, trial by
    trial, in the link-budget mode (which reads the region, the positions and the powers)."""
    from dpe5g.phy import deployment

    for fmt in ("json", "csv"):
        (workdir / f"mine.{fmt}").write_text(deployment.EXAMPLES[fmt])
    for mode in ("link-budget",):
        tables = []
        for fmt in ("json", "csv"):
            assert cli.main(["run", "--trials", "3", "--m", "4", "--snr-mode", mode, "--deployment", f"mine.{fmt}",
                             "--out", f"{mode}-{fmt}.csv"]) == 0
            tables.append([(r["trial"], r["error_m"], r["est_x_m"]) for r in read_csv(workdir / f"{mode}-{fmt}.csv")])
        assert tables[0] == tables[1] and len(tables[0]) >= 3
    capsys.readouterr()


def test_run_with_the_nlos_model_and_the_nlos_aware_receivers(workdir, capsys):
    """``--nlos-excess``, ``--los-mode``, ``--dpe-nlos`` and ``--otdoa-nlos`` set the experiment the book's NLoS
    chapter runs, and the summary shows every receiver with the paired differences."""
    assert cli.main(["run", "--trials", "2", "--snr-mode", "link-budget", "--centring", "otdoa", "--los-mode",
                     "two_of_four", "--nlos-excess", "UMa", "--dpe-nlos", "--otdoa-nlos", "--out", "n.csv"]) == 0
    out = capsys.readouterr().out
    cfg = csv_config(workdir / "n.csv")
    assert cfg["los_mode"] == "two_of_four" and cfg["dpe_nlos"] and cfg["otdoa_nlos"]
    assert cfg["clock_window"] == "clock_nlos" and cfg["nlos_prior"] == "scenario"
    assert abs(cfg["nlos_excess_median_s"] - 10 ** -7.4) < 1e-15 and cfg["nlos_excess_sigma_lg"] == 0.2
    assert "LoS two_of_four, NLoS excess delay median 39.8 ns" in out
    assert "NLoS-aware DPE less NLoS-aware OTDoA on the same trials" in out
    assert "NLoS-aware DPE less OTDoA (first_path ToA) on the same trials" in out


def test_progress_shows_on_a_terminal_or_when_asked_and_never_with_quiet(workdir, capsys, monkeypatch):
    """A long command shows its progress on stderr when stderr is a terminal or with --progress, not otherwise and
    never with --quiet (its result lines are printed either way)."""
    args = ["run", "--trials", "2", "--snr", "20", "--m", "6", "--centring", "truth", "--force", "--out", "p.csv"]
    for seed, (extra, shown) in enumerate((([], False), (["--progress"], True), (["--quiet"], False))):
        assert cli.main(args + extra + ["--seed", str(seed)]) == 0  # (a new seed: computed, not read from the cache)
        out, err = capsys.readouterr()
        assert ("run trials" in err) is shown and "wrote p.csv" in out, (extra, err)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    assert cli.show_progress(cli.build_parser().parse_args(args))
    assert not cli.show_progress(cli.build_parser().parse_args(args + ["--quiet"]))
    assert cli.main(args + ["--progress", "--quiet"]) == 2
    assert "not allowed with argument" in capsys.readouterr().err
