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
