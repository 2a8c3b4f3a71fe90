"""The results store (``figures/trials``): it holds every experiment the book and the figures read, within its size
budget; the engine serves them from it without computing; and a random sample of its trials, recomputed today,
equals what it holds (a new sample each run: the seed is printed in the test header, DPE5G_VERIFY_SEED repeats it)."""

import json
import os

import numpy as np
import pytest

from dpe5g.common import locations
from dpe5g.receivers import otdoa
from dpe5g.simulation import engine, store, verify
from dpe5g.studies import catalog, paper
from dpe5g.figures import registry as figures

#: the store's size budget: 25 MB in all (issue 31), 30 MB since the UMi excess-delay runs (issue 41), 50 MB with the
#: ray-traced city (issue 45)
STORE_BUDGET_BYTES = 50_000_000


def test_store_holds_every_experiment_the_book_and_figures_read():
    missing = [e.run.name for e in catalog.store_experiments() if store.stored(e) is None]
    assert not missing, f"the results store lacks {missing}; run `make reproduce`"
    entries = sorted(p for p in locations.STORE_DIR.rglob("*") if p.is_file())  # the traced cities' folder too
    size = sum(p.stat().st_size for p in entries)
    assert size <= STORE_BUDGET_BYTES, \
        f"results store is {size / 1e6:.1f} MB, over its {STORE_BUDGET_BYTES / 1e6:g} MB budget"
    for e in catalog.store_experiments():
        meta = store.stored(e).meta
        assert meta["config_key"] == e.config_key() and meta["code_version"] and meta["commit"]


def test_stored_trials_are_what_the_code_computes():
    seed = int(os.environ["DPE5G_VERIFY_SEED"])  # set once per session by conftest.py, printed in the header
    found, done = verify.verify_sample(seed, catalog.store_experiments())  # SAMPLE_TRIALS trials of each experiment of SAMPLE_FAMILIES families
    assert len(done) >= verify.SAMPLE_FAMILIES
    assert not found, "\n".join(map(str, found[:20]))


@pytest.fixture
def small(tmp_path, monkeypatch):
    """A 6-trial experiment stored in a store of its own (DPE5G_STORE), computed without it."""
    monkeypatch.setenv("DPE5G_STORE", str(tmp_path / "store"))
    e = paper.fig9_truth(6).replace(name="small", chunk_trials=3)
    res = engine.run(e, cache=tmp_path / "cache", progress=False, use_store=False)
    return e, res, store.write_stored(e, {k: getattr(res, k) for k in store.stored_fields(e)})


def test_a_stored_run_is_read_not_computed(small, monkeypatch):
    e, res, _ = small

    def no_compute(*a, **k):
        raise AssertionError("the engine computed a trial the store holds")

    monkeypatch.setattr(engine, "ChunkRunner", no_compute)
    got = engine.run(e.replace(n_trials=4), progress=False)  # a prefix of the stored trials
    for k in store.stored_fields(e):  # as computed, to the bit
        np.testing.assert_array_equal(getattr(got, k), np.asarray(getattr(res, k))[:4], err_msg=k)
    with pytest.raises(AssertionError, match="computed a trial"):
        engine.run(e.replace(n_trials=7), progress=False)  # more trials than stored: computed


def restore(e, entry, arrays):
    """Write ``arrays`` as ``e``'s entry with a checksum of their own, as an entry computed by other code is."""
    store.write_stored(e, arrays, root=entry.npz.parent, code={"code_version": "other", "commit": None})


def test_a_changed_stored_value_is_named_with_the_remedy(small):
    e, _, entry = small
    arrays = dict(np.load(entry.npz))
    arrays["error_m"] = arrays["error_m"].copy()
    arrays["error_m"][4, 1, 0] *= 1.0 + 1e-8  # 10 times the verification's tolerance
    arrays["los"] = arrays["los"].copy()
    arrays["los"][1, 0] = ~arrays["los"][1, 0]
    restore(e, entry, arrays)
    found, done = verify.verify_sample(0, [e], 1, 6)
    assert done == [("small", [0, 1, 2, 3, 4, 5])]
    assert [(m.trial, m.field) for m in found] == [(4, "error_m"), (1, "los")]
    assert "results store: small, trial 4, field error_m" in str(found[0]) and "make reproduce" in str(found[0])


def test_a_gap_is_compared_absolutely_other_floats_relatively():
    """The certified gap, a relative difference of two costs, may move by VERIFY_RTOL absolutely when its costs move
    by VERIFY_RTOL relatively (``verify.ABSOLUTE_FIELDS``); every other float must hold VERIFY_RTOL relative."""
    tol = verify.VERIFY_RTOL
    stored = {"gap": np.array([1e-7, 1e-7, np.nan]), "error_m": np.array([1e-7, 1e-7, 2.0])}
    computed = {"gap": np.array([1e-7 + 0.5 * tol, 1e-7 + 2 * tol, np.nan]),
                "error_m": np.array([1e-7 * (1 + 0.5 * tol), 1e-7 + 0.5 * tol, 2.0])}
    found = verify.differences("x", [0, 1, 2], stored, computed)
    assert [(m.trial, m.field) for m in found] == [(1, "error_m"), (1, "gap")]


def test_an_otdoa_experiments_positions_may_differ_by_the_polishs_precision():
    """Where the OTDoA fix enters (``verify.position_atol``), positions and distances may differ by
    ``otdoa.POSITION_ATOL_M`` absolutely (the convex solver's last digits differ between CPUs, and the
    Gauss-Newton polish stops at 1 µm steps); elsewhere they may not, and no other field gets that tolerance."""
    from dpe5g.studies import paper

    step = otdoa.POSITION_ATOL_M
    assert verify.position_atol(paper.fig10()[("pr_los", "otdoa")]) == step
    assert verify.position_atol(paper.fig10()[("pr_los", "truth")]) == 0.0  # grid on the truth, no OTDoA
    stored = {"otdoa_xyz": np.array([23.9385039, 23.9385039]), "error_m": np.array([0.55, 0.55]),
              "clock_bias_s": np.array([1e-8, 1e-8])}
    computed = {"otdoa_xyz": np.array([23.9385039 + 0.5 * step, 23.9385039 + 2 * step]),
                "error_m": np.array([0.55 + 0.5 * step, 0.55]), "clock_bias_s": np.array([1e-8 + 1e-15, 1e-8])}
    found = verify.differences("x", [0, 1], stored, computed, position_atol_m=step)
    assert [(m.trial, m.field) for m in found] == [(0, "clock_bias_s"), (1, "otdoa_xyz")]
    found = verify.differences("x", [0, 1], stored, computed)
    assert [(m.trial, m.field) for m in found] == [(0, "clock_bias_s"), (0, "error_m"), (0, "otdoa_xyz"),
                                                    (1, "otdoa_xyz")]


def test_reproduce_reports_and_rewrites(small, capsys):
    e, _, entry = small
    arrays = dict(np.load(entry.npz))
    arrays["ue_xyz"] = arrays["ue_xyz"] + 1.0
    restore(e, entry, arrays)
    found = verify.reproduce([e], progress=False)
    assert {m.trial for m in found} == set(range(6)) and {m.field for m in found} == {"ue_xyz"}
    assert verify.reproduce([e], progress=False) == []  # rewritten: now what the code computes


def simulated_coverage_runs(n_families: int, per_run: int, reps: int, seed: int) -> np.ndarray:
    """Runs until every one of n_families has been drawn, per_run distinct families a run, in reps simulations."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(reps):
        seen, r = set(), 0
        while len(seen) < n_families:
            seen |= set(rng.choice(n_families, per_run, replace=False).tolist())
            r += 1
        runs.append(r)
    return np.asarray(runs)


def test_coverage_runs_matches_a_simulation():
    runs = simulated_coverage_runs(10, 3, 2000, seed=0)
    mean, q95 = verify.coverage_runs(10, 3)
    assert abs(mean - np.mean(runs)) < 0.15 and abs(q95 - np.quantile(runs, 0.95)) <= 1


def test_verify_command_prints_its_seed_and_names_mismatches(small, monkeypatch, capsys):
    from dpe5g.cli import main as cli

    e, _, entry = small
    monkeypatch.setattr(catalog, "store_experiments", lambda: [e])
    assert cli.main(["verify", "--seed", "5", "--families", "1", "--trials", "2"]) == 0
    assert "verify: seed 5 (dpe5g verify --seed 5 repeats this sample)" in capsys.readouterr().out
    arrays = dict(np.load(entry.npz))
    arrays["edge"] = ~arrays["edge"]
    restore(e, entry, arrays)
    assert cli.main(["verify", "--seed", "5", "--families", "1", "--trials", "2"]) == 1
    assert "field edge" in capsys.readouterr().err
    np.savez_compressed(entry.npz, **{**arrays, "edge": ~arrays["edge"]})  # damaged: another checksum
    assert cli.main(["verify", "--seed", "5", "--families", "1", "--trials", "2"]) == 1
    out, err = capsys.readouterr()
    assert "1 damaged" in out and err.count("is damaged") == 1 and "make reproduce" in err, (out, err)
    assert cli.main(["verify", "--families", "0"]) == 2
    assert "--families must be an integer in [1, 10000], got 0" in capsys.readouterr().err


def test_verify_reports_each_mismatch_as_it_finds_it(small, monkeypatch, capsys):
    """dpe5g verify prints a mismatch as soon as its experiment is compared: a check stopped part-way (Ctrl-C in the
    next experiment) has already told what it found."""
    from dpe5g.cli import main as cli

    e, _, entry = small
    other = e.replace(name=e.run.name + "-next")
    monkeypatch.setattr(catalog, "store_experiments", lambda: [e, other])
    monkeypatch.setattr(verify, "families", lambda exps: [list(exps)])  # one family: e first, then the next
    arrays = dict(np.load(entry.npz))
    arrays["edge"] = ~arrays["edge"]
    restore(e, entry, arrays)
    real = verify.recompute

    def recompute(exp, picked):
        if exp is other:
            raise KeyboardInterrupt
        return real(exp, picked)

    monkeypatch.setattr(verify, "recompute", recompute)
    monkeypatch.setattr(store, "stored", lambda exp, _real=store.stored: _real(e) if exp is other else _real(exp))
    assert cli.main(["verify", "--seed", "5", "--families", "1", "--trials", "2"]) == 130
    err = capsys.readouterr().err
    assert "field edge" in err, err


def test_coverage_runs_stays_exact_for_many_families():
    """85 families (the store's count once the NLoS study joined it): inclusion–exclusion over the families never
    drawn cancelled catastrophically there (a mean of 571449 runs); the chain of undrawn families agrees with a
    simulation."""
    runs = simulated_coverage_runs(85, 3, 400, seed=1)
    mean, q95 = verify.coverage_runs(85, 3)
    assert abs(mean - np.mean(runs)) < 6 and abs(q95 - np.quantile(runs, 0.95)) < 15


def damage(kind: str, entry) -> None:
    """Damage a store entry as a disk, an editor or a bad merge would."""
    npz, meta_path = entry.npz, entry.npz.with_suffix(".json")
    if kind == "edited value":  # a valid file, one value changed
        arrays = dict(np.load(npz))
        arrays["error_m"] = arrays["error_m"] * np.where(np.arange(arrays["error_m"].size) == 7, 1.01, 1.0).reshape(
            arrays["error_m"].shape)
        np.savez_compressed(npz, **arrays)
    elif kind in ("more trials claimed", "fewer trials claimed"):
        meta = json.loads(meta_path.read_text())
        claimed = 2 * meta["n_trials"] if kind.startswith("more") else meta["n_trials"] // 2
        meta_path.write_text(json.dumps({**meta, "n_trials": claimed}))
    elif kind == "truncated":
        npz.write_bytes(npz.read_bytes()[: npz.stat().st_size // 2])
    elif kind == "bit flipped":
        data = bytearray(npz.read_bytes())
        data[len(data) // 2] ^= 0x10
        npz.write_bytes(bytes(data))
    elif kind == "invalid JSON":
        meta_path.write_text(meta_path.read_text()[:-40])
    elif kind == "arrays missing":
        npz.unlink()
    elif kind == ".json missing":
        meta_path.unlink()


DAMAGES = ("edited value", "more trials claimed", "fewer trials claimed", "truncated", "bit flipped", "invalid JSON",
           "arrays missing", ".json missing")


def test_a_damaged_entry_is_named_and_make_reproduce_repairs_it(small, tmp_path, monkeypatch, capsys):
    """Each kind of damage: reading the entry (a run, the CLI, the store check) is one line naming the file and
    `make reproduce`, never a number; `reproduce` then rewrites the entry without reading it, to the same bits."""
    from dpe5g.cli import main as cli
    from dpe5g.common.errors import DamagedEntry

    e, res, entry = small
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path / "cache"))  # the fixture's chunks: reproduce computes nothing
    monkeypatch.chdir(tmp_path)
    for kind in DAMAGES:
        damage(kind, entry)
        with pytest.raises(DamagedEntry, match=f"{entry.npz.stem}.* is damaged .*make reproduce") as err:
            engine.run(e.replace(n_trials=4), progress=False)
        assert [str(d) for d in store.check_store()] == [str(err.value)], kind
        args = ["run", "--trials", "6", "--centring", "truth", "--out", f"{kind}.csv"]  # the entry's experiment
        assert cli.main(args) == 1, kind
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and "is damaged" in lines[0] and not (tmp_path / f"{kind}.csv").exists(), lines
        assert verify.reproduce([e], progress=False, log=None) == []  # no trial compared: the entry was damaged
        got = engine.run(e, progress=False)
        for k in store.stored_fields(e):
            np.testing.assert_array_equal(getattr(got, k), getattr(res, k), err_msg=f"{kind}: {k}")
        assert store.check_store() == []


def test_every_committed_entry_matches_its_checksum():
    assert [str(d) for d in store.check_store(locations.STORE_DIR)] == []
    for meta in locations.STORE_DIR.glob("*.json"):
        assert len(json.loads(meta.read_text())["arrays_sha256"]) == 64, meta


def test_no_bit_flip_of_an_entry_escapes_as_another_error(small):
    """A flipped bit in a zip's or an .npy header's bytes raises anything from BadZipFile to SyntaxError,
    NotImplementedError or RuntimeError inside NumPy and zipfile; each is an ``errors.DamagedEntry`` naming the file,
    or (a bit of zip metadata nothing reads) the arrays as stored.  Every byte of the entry, one bit each."""
    from dpe5g.common.errors import DamagedEntry

    _, _, entry = small
    data = entry.npz.read_bytes()
    good = entry.check()
    outcomes = set()
    for i in range(len(data)):
        entry.npz.write_bytes(data[:i] + bytes([data[i] ^ (1 << (i % 8))]) + data[i + 1:])
        try:
            held = entry.check()
        except DamagedEntry as err:
            assert str(entry.npz) in str(err) and "make reproduce" in str(err)
            outcomes.add("damaged")
            continue
        assert sorted(held) == sorted(good) and all(np.array_equal(held[k], good[k], equal_nan=True) for k in good)
        outcomes.add("intact")
    assert "damaged" in outcomes


def test_reproduce_removes_a_damaged_file_of_no_experiment(small, tmp_path, monkeypatch):
    """A stray or stale damaged file stops every read of the store (``check_store``); reproduce removes it, and
    leaves an undamaged stranger alone."""
    e, _, entry = small
    monkeypatch.setenv("DPE5G_CACHE", str(tmp_path / "cache"))
    root = entry.npz.parent
    (root / "stray-0123456789abcdef.json").write_text("{}")
    (root / "orphan-0123456789abcdef.npz").write_bytes(b"not a zip")
    assert len(store.check_store()) == 2
    verify.reproduce([e], progress=False, log=None)
    assert store.check_store() == [] and sorted(p.name for p in root.iterdir()) == sorted(
        [entry.npz.name, entry.npz.with_suffix(".json").name])


def test_a_payload_is_checked_against_its_checksum(tmp_path, capsys):
    figures.save_payload("fig_x", None, {"rmse_m": [1.25, 2.5]}, cache=tmp_path)
    assert figures.load_payload("fig_x", None, cache=tmp_path) == {"rmse_m": [1.25, 2.5]}
    path = figures.payload_path("fig_x", None, cache=tmp_path)
    for bad in (path.read_text().replace("1.25", "12.5"), "[]", path.read_text()[:20]):
        path.write_text(bad)
        assert figures.load_payload("fig_x", None, cache=tmp_path) is None
        assert "is damaged" in capsys.readouterr().err and not path.exists()
        assert path.with_name(path.name + ".damaged").read_text() == bad


def test_a_store_variable_naming_a_file_is_named(tmp_path, monkeypatch):
    (tmp_path / "afile").write_text("x")
    monkeypatch.setenv("DPE5G_STORE", str(tmp_path / "afile"))
    with pytest.raises(ValueError, match="DPE5G_STORE=.*afile: is not a folder"):
        store.stored(paper.fig9_truth(6))


def test_reproduce_refuses_changed_code_unless_told(tmp_path, monkeypatch, capsys):
    """``dpe5g reproduce`` (``make reproduce``) on a tree whose code differs from its commit stops with one line
    (exit 2) before computing anything; with --allow-dirty it runs."""
    from dpe5g.cli import main as cli

    import shutil

    shutil.copytree(locations.STORE_DIR / "cities", tmp_path / "store" / "cities")  # (a store holds its cities)
    monkeypatch.setenv("DPE5G_STORE", str(tmp_path / "store"))
    monkeypatch.setattr(store, "code_changes", lambda root=None: ["dpe5g/receivers/cost.py"])
    ran = []
    monkeypatch.setattr(verify, "reproduce", lambda exps, **kw: ran.append(kw) or [])
    assert cli.main(["reproduce"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the code differs from its commit (dpe5g/receivers/cost.py)" in err and not ran
    assert cli.main(["reproduce", "--allow-dirty"]) == 0 and len(ran) == 1


def test_git_commit_names_the_commit_and_a_digest_of_the_changes(tmp_path):
    """An entry records the commit; where the code differs from it, a digest of the changes that is the same for the
    same changes and differs for others; files outside ``store.CODE_PATHS`` do not count."""
    import subprocess

    git = lambda *a: subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@example.org", *a], cwd=tmp_path,
                                    check=True, capture_output=True, text=True).stdout.strip()
    git("init", "-q")
    (tmp_path / "dpe5g").mkdir()
    (tmp_path / "dpe5g" / "cost.py").write_text("x = 1\n")
    (tmp_path / "notes.md").write_text("notes\n")
    git("add", ".")
    git("commit", "-q", "-m", "code")
    head = git("rev-parse", "HEAD")
    assert store.git_commit(tmp_path) == head and store.code_changes(tmp_path) == []
    (tmp_path / "notes.md").write_text("other notes\n")  # not code
    assert store.git_commit(tmp_path) == head
    (tmp_path / "dpe5g" / "cost.py").write_text("x = 2\n")
    first = store.git_commit(tmp_path)
    assert first.startswith(head + "+diff.") and len(first) == len(head) + 18
    assert store.git_commit(tmp_path) == first and store.code_changes(tmp_path) == ["dpe5g/cost.py"]
    (tmp_path / "dpe5g" / "new.py").write_text("y = 1\n")  # an untracked module counts
    second = store.git_commit(tmp_path)
    assert second != first and store.code_changes(tmp_path) == ["dpe5g/cost.py", "dpe5g/new.py"]
    (tmp_path / "dpe5g" / "new.py").write_text("y = 2\n")
    assert store.git_commit(tmp_path) not in (first, second)
    assert store.git_commit(tmp_path / "nowhere") is None
