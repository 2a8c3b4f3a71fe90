"""README.md's and book/running.md's result and benchmark tables are generated from the committed data; they must
not drift; README.md stays short (at most 120 lines) and names no path outside the repository."""

import functools
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "readme_tables.py"


@pytest.fixture(scope="module")
def tables():
    """scripts/readme_tables.py loaded as a module, each table generated once for the tests below (what the second
    tests is the comparison and the rewrite)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("readme_tables", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.TABLES = {name: functools.cache(fn) for name, fn in mod.TABLES.items()}
    return mod


def test_readme_tables_match_the_committed_data(tables, capsys):
    assert tables.main(["--check"]) == 0, capsys.readouterr().err


def test_readme_check_notices_a_stale_table(tables, tmp_path, monkeypatch):
    mod = tables
    for attr, name, block in (("README", "README.md", "found"), ("RUNNING", "running.md", "fig9")):
        real = getattr(mod, attr)
        stale = real.read_text().replace(f"<!-- begin:{block} -->\n", f"<!-- begin:{block} -->\n| 99 |\n", 1)
        fake = tmp_path / name
        fake.write_text(stale)
        monkeypatch.setattr(mod, attr, fake)
        assert mod.main(["--check"]) == 1
        assert mod.main([]) == 0 and fake.read_text() == real.read_text()
        monkeypatch.setattr(mod, attr, real)


def test_readme_is_short_and_stays_in_the_repository():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 120
    assert "../" not in text


def test_fresh_check_log_parsing():
    import importlib.util

    spec = importlib.util.spec_from_file_location("fresh_check_times", ROOT / "scripts" / "fresh_check_times.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    log = ("/tmp/x/chapters/05_rmse_vs_snr.md: Executed notebook in 512.5 seconds [mystnb]\n"
           "/tmp/x/chapters/01_tdl_channel.md: Executed notebook in 9.8 seconds [mystnb]\n"
           "============================= slowest 40 durations =============================\n"
           "12.50s call     tests/a/test_x.py::test_slow[1]\n"
           "32.20s setup    tests/b/test_y.py::test_slower\n"
           "=============== 234 passed, 1 skipped in 197.30s (0:03:17) ===============\n"
           "fresh-check test: passed in 1234s on a clean clone\n")
    rec = mod.parse(log)
    assert rec == {"make_test_s": 1234, "chapters_s": {"05_rmse_vs_snr": 512.5, "01_tdl_channel": 9.8},
                   "pytest_s": 197.3, "tests_passed": 234, "tests_skipped": 1,
                   "slowest_tests": [[32.2, "setup", "tests/b/test_y.py::test_slower"],
                                     [12.5, "call", "tests/a/test_x.py::test_slow[1]"]]}
    with pytest.raises(ValueError, match="lacks"):
        mod.parse(log.replace("fresh-check test: passed", "fresh-check test: FAILED"))
    # make test's two pytest runs (the tests that need no book, then those marked "book"): counts summed
    two = log.replace("fresh-check", "====== 20 passed in 31.50s ======\nfresh-check")
    assert mod.parse(two) == {**rec, "pytest_s": 197.3 + 31.5, "tests_passed": 254, "pytest_runs_s": [197.3, 31.5]}


def test_the_landing_page_and_readme_list_every_page_of_the_toc():
    """book/intro.md's "How to read it" table links every page of book/_toc.yml once, in its order; README's list
    of pages is generated from the same file (``readme_tables.chapters_text``, kept current by the check above)."""
    import re

    import yaml

    toc = yaml.safe_load((ROOT / "book" / "_toc.yml").read_text())
    pages = [entry["file"] for entry in toc["chapters"]]
    intro = (ROOT / "book" / "intro.md").read_text()
    table = intro.split("## How to read it", 1)[1].split("\n## ", 1)[0]
    targets = re.findall(r"^\| \{doc\}`([^`]+)`", table, re.M)
    linked = [t[3:] if t.startswith("../") else "book/" + t for t in targets]
    assert linked == pages, (linked, pages)
    readme = (ROOT / "README.md").read_text()
    assert all(f"`{p}.md`" in readme for p in pages)


def _readme_block(language: str, after: str) -> str:
    """The first ```language block of README.md after the line containing ``after``."""
    text = (ROOT / "README.md").read_text()
    rest = text[text.index(after):]
    start = rest.index(f"```{language}\n") + len(language) + 4
    return rest[start:rest.index("```\n", start)]


#: a small deployment of the issue that found README's first run failing: 8 BSs in a 300 m square
SMALL_DEPLOYMENT = {
    "base_stations": [{"id": f"bs{i}", "x_m": x, "y_m": y, "height_m": 10.0, "power_dbm": 24.0}
                      for i, (x, y) in enumerate([(20, 20), (150, 10), (280, 25), (15, 150), (285, 145), (25, 280),
                                                  (150, 290), (275, 275)])],
    "region": {"x_min_m": 0.0, "y_min_m": 0.0, "x_max_m": 300.0, "y_max_m": 300.0}}


def test_readme_first_run_works_on_a_small_deployment(tmp_path):
    """README's commands for a first run on one's own deployment, run verbatim (``.venv/bin/dpe5g`` is this
    environment's) on an 8-BS deployment; the CSV they write reads with the csv module's defaults (a header first,
    one value per cell) and its provenance with ``json.load``."""
    import csv
    import json
    import shlex

    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    (tmp_path / ".venv" / "bin" / "dpe5g").symlink_to(Path(sys.executable).parent / "dpe5g")
    (tmp_path / "mine.json").write_text(json.dumps(SMALL_DEPLOYMENT))
    commands = [ln.split("#")[0] for ln in _readme_block("text", "A first run on your own").splitlines()]
    assert len(commands) == 2
    for command in commands:
        r = subprocess.run(shlex.split(command), cwd=tmp_path, capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (command, r.stderr[-2000:])
    with open(tmp_path / "study.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    with open(tmp_path / "study.json") as f:
        meta = json.load(f)
    assert set(rows[0]) == set(meta["columns"]), "the sidecar describes every column"
    assert {r["m"] for r in rows} == {"6", "8"}  # the paper's M that fit 8 BSs, and all 8
    assert len(rows) == meta["experiment"]["n_trials"] * len(meta["experiment"]["snrs_db"]) * 2
    assert all(float(r["error_m"]) >= 0 and ";" not in "".join(r.values()) for r in rows)


def test_readme_python_quick_start_runs():
    """README's Python quick start (at most 15 lines) runs as it is and prints a certified fix near its UE."""
    import re

    code = _readme_block("python", "In Python")
    assert len(code.strip().splitlines()) <= 15
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.fullmatch(r"fix \[\s*([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s*\] m, clock bias ([-\d.]+) ns, certified True, "
                     r"on the window's edge False\n",
                     r.stdout)
    assert m, r.stdout
    assert abs(float(m[1]) - 120.0) < 0.5 and abs(float(m[2]) - 80.0) < 0.5 and abs(float(m[4]) - 3.0) < 1.0


def test_the_licence_and_the_citation_agree_with_the_project():
    """LICENSE is the licence pyproject.toml and CITATION.cff state; CITATION.cff cites the software and, as its
    preferred citation, the paper README links."""
    import tomllib

    import yaml

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert (ROOT / "LICENSE").read_text().startswith(f"{project['license']['text']} License\n")
    assert cff["license"] == project["license"]["text"] and cff["version"] == project["version"]
    assert cff["type"] == "software" and cff["authors"] == [{"name": project["authors"][0]["name"]}]
    paper = cff["preferred-citation"]
    arxiv = paper["identifiers"][0]["value"].removeprefix("arXiv:")
    assert f"arxiv.org/abs/{arxiv}" in (ROOT / "README.md").read_text() and paper["url"].endswith(arxiv)
    assert [a["family-names"] for a in paper["authors"]] == ["Li", "Vicenzo", "Xu"]
