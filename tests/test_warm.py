"""``dpe5g warm`` fills the Monte Carlo cache with the book's runs: every run a chapter asks for must be on its list
(``paper.book_experiments``), or warm leaves it to the book (slower, never wrong)."""

import json
from pathlib import Path

import pytest

from dpe5g import paper, store

ROOT = Path(__file__).resolve().parents[1]
RUN_LOG = ROOT / ".cache" / "book-runs.jsonl"  # written by the book build (Makefile, DPE5G_RUN_LOG)


@pytest.mark.book
def test_warm_knows_every_run_the_book_asks_for():
    if not RUN_LOG.exists():
        pytest.skip(f"no book build recorded its Monte Carlo runs here ({RUN_LOG}; `make book` writes it)")
    runs = [json.loads(line) for line in RUN_LOG.read_text().splitlines() if line.strip()]
    known = {store.cache_dir(e).name: e.run.n_trials for e in paper.book_experiments()}
    unknown = sorted({r["run"] for r in runs if r["run"] not in known})
    longer = sorted({f"{r['run']} ({r['n_trials']} > {known[r['run']]})" for r in runs
                     if r["run"] in known and r["n_trials"] > known[r["run"]]})
    assert not unknown and not longer, (
        f"paper.book_experiments misses runs the book made: {unknown}; runs with more trials than it lists: {longer}")
