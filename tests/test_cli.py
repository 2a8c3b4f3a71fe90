import subprocess
import sys

import pytest


def run(*args):
    return subprocess.run([sys.executable, "-m", "dpe5g", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(
    "args, needle",
    [
        (("profile", "C", "--delay-spread", "65"), "nanoseconds"),
        (("profile", "Z"), "profile must be one of"),
        (("profile", "C", "--delay-spread", "nan"), "finite"),
        (("figures", "--only", "fig99_nothing"), "figure must be one of"),
        (("figures", "--only", "fig01_tdl_a", "--trials", "5", "--out", "elsewhere"), "--trials applies to"),
        (("figures", "--trials", "5"), "holds the committed baselines"),
        (("figures", "--only", "fig09_rmse_vs_snr", "--trials", "0", "--out", "elsewhere"), "--trials must be"),
    ],
)
def test_bad_input_is_one_line_exit_2(args, needle):
    r = run(*args)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr


def test_bad_deployment_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "mine.csv"
    bad.write_text("id,x_m,y_m,height_m,power_dbm\nA,0,0,10,24\nB,100,0,10,24\nC,0,100,10000,24\n")
    r = run("deployment", str(bad))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "height_m must be in [1.5, 150] m" in r.stderr


def test_deployment_summary():
    r = run("deployment")
    assert r.returncode == 0 and "26 BSs" in r.stdout and "227,360 m2" in r.stdout


def test_profile_prints_table():
    r = run("profile", "D")
    assert r.returncode == 0
    assert "TDL-D" in r.stdout and "K = 13.3" in r.stdout


def test_figures_with_a_trial_count(tmp_path):
    """``dpe5g figures --trials N`` runs the paper's experiment (``dpe5g.paper``) with N trials."""
    import json
    import os

    env = {**os.environ, "DPE5G_CACHE": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-m", "dpe5g", "figures", "--only", "fig09_rmse_vs_snr", "--trials", "3",
                        "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out" / "data" / "fig09_rmse_vs_snr.json").read_text())
    assert {v["n_trials"] for v in doc["config"]["receivers"].values()} == {3}
