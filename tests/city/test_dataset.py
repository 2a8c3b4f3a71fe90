"""The traced city as one verified unit (issue 55): every kind of damage to its arrays, its record or its deployment
file is found and named in one line, makes the city stale for ``dpe5g trace`` (the repair) and is reported by the
store's check (``dpe5g verify``); a stop while a city is written never leaves one that reads as whole."""

import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from dpe5g.city import dataset, trace, trace_chunks
from dpe5g.common.errors import DamagedEntry
from dpe5g.common.locations import STORE_DIR
from dpe5g.phy import deployment
from dpe5g.simulation import store

NAME = "munich"


@pytest.fixture
def root(tmp_path):
    """A store holding a copy of the traced city (its paths, record, deployment and 3-D view)."""
    (tmp_path / dataset.CITY_FOLDER).mkdir()
    for suffix in (".npz", ".json", "_deployment.json", "_view.npz", "_view.json"):
        shutil.copy(STORE_DIR / dataset.CITY_FOLDER / f"{NAME}{suffix}", tmp_path / dataset.CITY_FOLDER)
    return tmp_path


def edit_json(path, change):
    doc = json.loads(path.read_text())
    path.write_text(json.dumps(change(doc), indent=1))


def flip_a_bit(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x10
    path.write_bytes(bytes(data))


def move_a_bs(doc):
    doc["base_stations"][3]["x_m"] += 30.0
    return doc


DAMAGE = {
    "a bit of the arrays": (lambda d: flip_a_bit(d / f"{NAME}.npz"), "cannot be read|do not match the checksum"),
    "the arrays missing": (lambda d: (d / f"{NAME}.npz").unlink(), f"{NAME}.npz is missing"),
    "the record missing": (lambda d: (d / f"{NAME}.json").unlink(), f"{NAME}.json is missing"),
    "the deployment missing": (lambda d: (d / f"{NAME}_deployment.json").unlink(), "deployment.json is missing"),
    "the arrays cut short": (lambda d: (d / f"{NAME}.npz").write_bytes((d / f"{NAME}.npz").read_bytes()[:5000]),
                             "cannot be read"),
    "a record of another scene": (lambda d: edit_json(d / f"{NAME}.json",
                                                      lambda m: {**m, "spec": {**m["spec"], "scene": "etoile"}}),
                                  "is not what was traced"),
    "a record that is a list": (lambda d: (d / f"{NAME}.json").write_text("[]"), "is not a city's record"),
    "a record without settings": (lambda d: edit_json(d / f"{NAME}.json", lambda m: {k: v for k, v in m.items()
                                                                                       if k != "spec"}),
                                  "does not name this city and its settings"),
    "a BS moved 30 m": (lambda d: edit_json(d / f"{NAME}_deployment.json", move_a_bs),
                        "base stations are not the traced ones"),
    "a BS fewer": (lambda d: edit_json(d / f"{NAME}_deployment.json",
                                       lambda doc: {**doc, "base_stations": doc["base_stations"][:-1]}),
                   "base stations are not the traced ones"),
}


def test_the_copy_is_whole_and_current(root):
    assert dataset.check_city(NAME, root) is None
    assert dataset.is_current(NAME, trace.CitySpec().to_dict(), trace.code_digest(), root)
    assert dataset.load_city(NAME, root).n_ue == 5000 and store.check_store(root) == []


@pytest.mark.parametrize("kind", DAMAGE)
def test_damage_is_named_stale_and_reported(root, kind):
    damage, needle = DAMAGE[kind]
    damage(root / dataset.CITY_FOLDER)
    found = dataset.check_city(NAME, root)
    assert found is not None and "\n" not in found
    with pytest.raises(DamagedEntry, match=rf"({needle}).*: dpe5g trace \(make reproduce\) traces the city again"):
        dataset.load_city(NAME, root)
    assert not dataset.is_current(NAME, trace.CitySpec().to_dict(), trace.code_digest(), root)  # trace repairs it
    assert [Path(d.path).name for d in store.check_store(root)] == [f"{NAME}.npz"]


def test_a_damaged_view_is_reported(root):
    flip_a_bit(root / dataset.CITY_FOLDER / f"{NAME}_view.npz")
    assert [Path(d.path).name for d in store.check_store(root)] == [f"{NAME}_view.npz"]


class Killed(BaseException):
    """A kill: nothing after it runs (the writer's clean-up included)."""


def tiny(root, shift_m: float = 0.0) -> dict:
    """The arrays of a small city: the stored city's first 20 UEs, its BSs moved ``shift_m`` east."""
    city = dataset.load_city(NAME, root)
    keep = city.link_ue < 20
    out = {k: getattr(city, k)[keep] if k.startswith("link_") or getattr(city, k).shape[:1] == keep.shape
           else getattr(city, k) for k in dataset.ARRAYS}
    out["ue_xyz"] = city.ue_xyz[:20]
    out["bs_xyz"] = city.bs_xyz + np.array([shift_m, 0.0, 0.0])
    return out


def steps(monkeypatch, kill_at: int | None) -> list:
    """Count ``_io.publish``'s steps (each file flushed, each rename): a ``Killed`` at step ``kill_at``."""
    from dpe5g.common import _io

    done = []

    def step(real):
        def counted(*a, **k):
            done.append(real.__name__)
            if len(done) == kill_at:
                raise Killed
            return real(*a, **k)
        return counted

    monkeypatch.setattr(_io, "fsync", step(_io.fsync))
    monkeypatch.setattr(_io.os, "rename", step(os.rename))
    monkeypatch.setattr(_io.os, "replace", step(os.replace))
    monkeypatch.setattr(_io.shutil, "rmtree", lambda *a, **k: None)  # (a kill cleans nothing up)
    return done


def test_a_kill_at_any_step_of_a_publication_leaves_the_old_city_or_the_new(root, monkeypatch):
    """``save_city`` publishes the paths, the deployment and the record as one unit (``_io.publish``): killed at any of
    its steps, the store holds the old city whole or the new one whole, never a mix, never damage; and the next
    publication of the city finishes or replaces the stopped one."""
    spec = dataset.load_city(NAME, root).spec
    old, new = tiny(root), tiny(root, shift_m=1.0)
    dataset.save_city("tiny", old, spec, {"code": "x"}, root)
    seen = set()
    for kill_at in range(1, 30):
        store_k = root / f"k{kill_at}"
        shutil.copytree(root / dataset.CITY_FOLDER, store_k / dataset.CITY_FOLDER)
        with monkeypatch.context() as m:
            done = steps(m, kill_at)
            try:
                dataset.save_city("tiny", new, spec, {"code": "x"}, store_k)
            except Killed:
                pass
        assert dataset.check_city("tiny", store_k) is None, (kill_at, done)
        bs = dataset.load_city("tiny", store_k).bs_xyz
        dep_file = store_k / dataset.CITY_FOLDER / "tiny_deployment.json"  # (as a city of one's own is named)
        assert np.array_equal(deployment.named(str(dep_file)).bs_xyz, bs), kill_at  # the paths' BSs, whichever
        seen.add("new" if np.array_equal(bs, new["bs_xyz"]) else "old" if np.array_equal(bs, old["bs_xyz"]) else "?")
        assert store.damaged_cities(store_k) == []
        dataset.save_city("tiny", old, spec, {"code": "x"}, store_k)
        assert np.array_equal(dataset.load_city("tiny", store_k).bs_xyz, old["bs_xyz"])
        assert [p.name for p in (store_k / dataset.CITY_FOLDER).glob(".tiny.publish")] == []
        if len(done) < kill_at:  # it ran to its end: every step was tried
            break
    assert seen == {"old", "new"} and kill_at > 5


def test_trace_leaves_a_current_city_untouched(monkeypatch, capsys):
    """``dpe5g trace`` on the stored city, current and whole: nothing traced, every file of ``cities/`` the same bytes
    and times; stopped, it says that nothing of the trace is kept."""
    from dpe5g.cli import main as cli
    from dpe5g.studies import city_sensitivity

    def refuse(*a, **k):
        raise AssertionError("the stored city is current: nothing may be traced")

    digest = trace.code_digest()  # (of the code before the stand-in below, which it reads)
    monkeypatch.setattr(trace, "code_digest", lambda: digest)
    monkeypatch.setattr(trace_chunks, "trace_city", refuse)
    monkeypatch.setattr(city_sensitivity, "trace_variant", refuse)
    folder = STORE_DIR / dataset.CITY_FOLDER
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())}
    assert cli.main(["trace"]) == 0
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(folder.iterdir())} == before
    assert "is whole and was traced with today's settings and code" in capsys.readouterr().out
    assert "nothing of this trace is kept" in cli.kept_on_stop("dpe5g trace")


def test_trace_honours_dpe5g_store(tmp_path, monkeypatch, capsys):
    """With DPE5G_STORE naming another store, ``dpe5g trace`` reads and writes the cities there: a copy of the current
    city is found current there, and an empty store is one to trace (here refused by a stand-in), whatever the
    checkout's store holds; the checkout's files stay as they are."""
    from dpe5g.cli import main as cli

    class Traces(Exception):
        pass

    def refuse(*a, **k):
        raise Traces

    digest = trace.code_digest()
    monkeypatch.setattr(trace, "code_digest", lambda: digest)
    monkeypatch.setattr(trace_chunks, "trace_city", refuse)
    folder = STORE_DIR / dataset.CITY_FOLDER
    before = {p: p.stat().st_mtime_ns for p in folder.iterdir()}
    shutil.copytree(folder, tmp_path / "copy" / dataset.CITY_FOLDER)
    monkeypatch.setenv("DPE5G_STORE", str(tmp_path / "copy"))
    assert cli.main(["trace"]) == 0
    assert f"{tmp_path / 'copy'}" in capsys.readouterr().out
    (tmp_path / "empty").mkdir()
    monkeypatch.setenv("DPE5G_STORE", str(tmp_path / "empty"))
    with pytest.raises(Traces):
        cli.main(["trace"])
    monkeypatch.setenv("DPE5G_STORE", "off")
    assert cli.main(["trace"]) == 2 and "DPE5G_STORE is 'off'" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in folder.iterdir()} == before


def test_reproduce_removes_no_city(root, monkeypatch):
    """``dpe5g reproduce`` removes damaged Monte Carlo entries of no experiment, never a city (``dpe5g trace`` repairs
    those): a damaged city's files are all still there after it."""
    from dpe5g.simulation import verify

    flip_a_bit(root / dataset.CITY_FOLDER / f"{NAME}.npz")
    files = sorted(p.name for p in (root / dataset.CITY_FOLDER).iterdir())
    monkeypatch.setenv("DPE5G_STORE", str(root))
    verify.reproduce([], progress=False, log=io.StringIO())
    assert sorted(p.name for p in (root / dataset.CITY_FOLDER).iterdir()) == files


def test_verify_names_a_missing_deployment_file_and_fails(tmp_path, monkeypatch, capsys):
    """``dpe5g verify`` on a store whose city lost its deployment file: the damage named and exit code 1 (it ended
    in exit 2 with "No such file or directory: munich", or hashed a file of that name in the working folder)."""
    from dpe5g.cli import main as cli

    root = tmp_path
    shutil.copytree(STORE_DIR / dataset.CITY_FOLDER, root / dataset.CITY_FOLDER)
    (root / dataset.CITY_FOLDER / f"{NAME}_deployment.json").unlink()
    monkeypatch.setenv("DPE5G_STORE", str(root))
    monkeypatch.chdir(root)
    (root / NAME).write_text("not a deployment")
    assert cli.main(["verify", "--seed", "1", "--families", "1", "--trials", "1"]) == 1
    err = capsys.readouterr().err
    assert f"{NAME}_deployment.json is missing" in err and "cannot be listed while the store is damaged" in err
