"""``dpe5g figures`` with the paper's experiment at a few trials, after the book has compiled its programs."""

import json
import os
import subprocess
import sys


def test_figures_with_a_trial_count(tmp_path):
    """``dpe5g figures --trials N`` runs the paper's experiment (``dpe5g.studies.paper``) with N trials.  A test of the book's: it
    compiles Fig. 9's three programs, which the book has put in JAX's compilation cache by then (beside the book's own
    compiles, at low priority, it took 536-600+ s of the 2-core machine; after it, about 20 s)."""
    env = {**os.environ, "DPE5G_CACHE": str(tmp_path / "cache")}
    r = subprocess.run([sys.executable, "-m", "dpe5g", "figures", "--only", "fig09_rmse_vs_snr", "--trials", "3",
                        "--out", str(tmp_path / "out")], capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / "out" / "data" / "fig09_rmse_vs_snr.json").read_text())
    assert {v["n_trials"] for v in doc["config"]["receivers"].values()} == {3}
