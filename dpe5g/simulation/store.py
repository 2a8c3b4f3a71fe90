"""The results store (``figures/trials``, committed; tier 1 of the results on disk, the cache ``chunk_cache`` is tier 2).

Per-trial results of every experiment the book and the figures read, keyed by the config
(``Experiment.config_key``), each entry recording the code that computed it; ``verify`` recomputes a sample of its
trials against today's code, ``dpe5g reproduce`` rewrites it.  Every entry records a checksum of its arrays
(``_io.arrays_digest``), checked whenever it is read: a damaged entry is an ``errors.DamagedEntry`` naming
the file and ``make reproduce``.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..common._io import arrays_digest, atomic_write, jsonable, read_npz
from ..common.errors import DamagedEntry
from ..common.locations import REPOSITORY, store_root
from ..city import dataset as city_paths
from .code_key import code_version, numerics
from .experiment import Experiment
from .results import Results

def store_digest() -> str:
    """SHA-256 of the results store's files (names and bytes): what the payloads of ``payload_path`` read besides
    the code.

    Returns
    -------
    str
        The hex digest; "off" when there is no store.
    """
    root = store_root()
    if root is None or not root.is_dir():
        return "off"
    h = hashlib.sha256()
    for path in sorted(p for p in root.iterdir() if p.suffix in (".npz", ".json")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def stored_fields(e: Experiment) -> tuple[str, ...]:
    """The fields of ``Results`` a store entry of an experiment holds.

    Parameters
    ----------
    e : Experiment
        The experiment.

    Returns
    -------
    tuple of str
        All of them (the OTDoA fields where ``e`` runs OTDoA, the NLoS-aware OTDoA's where it runs that).
    """
    return (Results.FIELDS + (Results.OTDOA_FIELDS if e.receiver.otdoa else ())
            + (Results.OTDOA_NLOS_FIELDS if e.receiver.otdoa_nlos else ()))


@dataclass(frozen=True)
class StoredRun:
    """One entry of the results store: ``<name>-<config key>.npz`` and the ``.json`` beside it.

    Attributes
    ----------
    npz : Path
        The arrays as computed (float64 included), trials on the leading axis, compressed.
    meta : dict
        The ``.json``: name, config, n_trials, fields, the arrays' checksum ``arrays_sha256``, code version and commit.
    """

    npz: Path
    meta: dict

    @property
    def n_trials(self) -> int:
        """The number of trials the entry holds."""
        return int(self.meta["n_trials"])

    def load(self, n_trials: int | None = None, trials=None) -> dict:
        """The stored arrays of some trials, after ``check``.

        Parameters
        ----------
        n_trials : int or None
            Trials 0 … n_trials-1; None: all.
        trials : array_like of int or None
            The trial indices to load instead.

        Returns
        -------
        dict
            The arrays by name, trials on the leading axis.
        """
        idx = slice(0, n_trials) if trials is None else np.asarray(trials)
        return {k: v[idx] for k, v in self.check().items()}

    def check(self) -> dict:
        """All the entry's arrays, read whole and checked against its ``.json``.

        Returns
        -------
        dict
            The arrays by name: the fields the ``.json`` lists, ``n_trials`` rows each, matching its checksum
            ``arrays_sha256`` (``arrays_digest``).

        Raises
        ------
        dpe5g.common.errors.DamagedEntry
            Naming the file, when a check fails.
        """
        try:
            arrays = read_npz(self.npz)
        except ValueError as err:
            raise DamagedEntry(self.npz, str(err)) from None
        if sorted(arrays) != sorted(self.meta["fields"]):
            raise DamagedEntry(self.npz, f"it holds the fields {sorted(arrays)}, its .json lists "
                                         f"{sorted(self.meta['fields'])}")
        rows = {k: v.shape[0] if v.ndim else 0 for k, v in arrays.items()}
        if set(rows.values()) != {self.n_trials}:
            raise DamagedEntry(self.npz, f"its .json records {self.n_trials} trials, its arrays hold "
                                         f"{sorted(set(rows.values()))} rows")
        if arrays_digest(arrays) != self.meta["arrays_sha256"]:
            raise DamagedEntry(self.npz, "its arrays do not match the checksum its .json records")
        return arrays


#: what an entry's ``.json`` must hold (``read_entry_meta``)
ENTRY_KEYS = {"name": str, "config_key": str, "n_trials": int, "fields": dict, "arrays_sha256": str}


def read_entry_meta(meta_path: Path) -> dict:
    """An entry's ``.json``, checked to hold ``ENTRY_KEYS`` with their types and to have its ``.npz`` beside it.

    Parameters
    ----------
    meta_path : Path
        The ``.json``.

    Returns
    -------
    dict
        Its content.

    Raises
    ------
    dpe5g.common.errors.DamagedEntry
        Naming the file, when a check fails.
    """
    try:
        meta = json.loads(Path(meta_path).read_text())
    except (OSError, ValueError) as err:  # (UnicodeDecodeError included)
        raise DamagedEntry(meta_path, f"not readable JSON: {' '.join(str(err).split())}") from None
    bad = [k for k, t in ENTRY_KEYS.items() if not isinstance(meta, dict) or not isinstance(meta.get(k), t)
           or isinstance(meta.get(k), bool)]
    if bad:
        raise DamagedEntry(meta_path, f"it lacks {', '.join(bad)} or has the wrong type there")
    if not Path(meta_path).with_suffix(".npz").exists():
        raise DamagedEntry(meta_path, f"its arrays, {Path(meta_path).with_suffix('.npz').name}, are missing")
    return meta


def stored(e: Experiment, root: Path | None = None) -> StoredRun | None:
    """The store's entry for ``e``: the same config key, at least ``e.run.n_trials`` trials.

    Trial t depends only on the config, the seed and t, so an entry of N trials serves any run of n ≤ N.

    Parameters
    ----------
    e : Experiment
        The experiment.
    root : Path or None
        The store's folder; None: ``store_root()``.

    Returns
    -------
    StoredRun or None
        The entry, checked when read (``StoredRun.load``); None if the store holds none or is off.

    Raises
    ------
    dpe5g.common.errors.DamagedEntry
        For a damaged ``.json``, an ``.npz`` without its ``.json``, or a shorter entry that fails its check.
    """
    root = store_root() if root is None else root
    if root is None or not root.is_dir():
        return None
    key = e.config_key()
    if missing_json := orphans(root, f"*-{key}.npz"):
        raise missing_json[0]
    for meta_path in sorted(root.glob(f"*-{key}.json")):
        entry = StoredRun(meta_path.with_suffix(".npz"), read_entry_meta(meta_path))
        if entry.n_trials >= e.run.n_trials:
            return entry
        entry.check()  # too short to serve: read anyway, so that a .json that understates its arrays is named
    return None


def orphans(root: Path, pattern: str) -> list[DamagedEntry]:
    """The store's ``.npz`` files whose ``.json`` is missing.

    Parameters
    ----------
    root : Path
        The store's folder.
    pattern : str
        A glob of the ``.npz`` files to look at.

    Returns
    -------
    list of errors.DamagedEntry
        One per such file.
    """
    return [DamagedEntry(npz, f"its .json, {npz.with_suffix('.json').name}, is missing")
            for npz in sorted(root.glob(pattern)) if not npz.with_suffix(".json").exists()]


def check_store(root: Path | None = None) -> list[DamagedEntry]:
    """Every entry of the store and every traced city, read and checked (``damaged_entries``, ``damaged_cities``).

    Parameters
    ----------
    root : Path or None
        The store's folder; None: ``store_root()``.

    Returns
    -------
    list of errors.DamagedEntry
        The damaged entries, any ``.npz`` without its ``.json``, and the damaged cities and views; empty when there
        is no store.
    """
    root = store_root() if root is None else root
    if root is None or not root.is_dir():
        return []
    return damaged_entries(root) + damaged_cities(root)


def damaged_entries(root: Path) -> list[DamagedEntry]:
    """The Monte Carlo entries of the store that are damaged (``read_entry_meta``, ``StoredRun.check``), and any
    ``.npz`` without its ``.json``; the traced cities are ``damaged_cities``'.

    Parameters
    ----------
    root : Path
        The store's folder.

    Returns
    -------
    list of errors.DamagedEntry
    """
    found = orphans(root, "*.npz")
    for meta_path in sorted(root.glob("*.json")):
        try:
            StoredRun(meta_path.with_suffix(".npz"), read_entry_meta(meta_path)).check()
        except DamagedEntry as err:
            found.append(err)
    return found


def damaged_cities(root: Path) -> list[DamagedEntry]:
    """The traced cities of the store (``city.dataset``) that are not whole, each with what is wrong, and their 3-D
    views that do not match their checksums.

    Parameters
    ----------
    root : Path
        The store's folder.

    Returns
    -------
    list of errors.DamagedEntry
    """
    found = []
    folder = city_paths.city_folder(root)
    names = {p.name.removesuffix(s) for s in city_paths.PARTS for p in folder.glob(f"*{s}")}
    names |= {p.name[1:].removesuffix(".publish") for p in folder.glob(".*.publish")}  # (a publication stopped early)
    for name in sorted(n for n in names if not n.endswith(("_view", "_deployment", "-materials"))):
        if (damage := city_paths.check_city(name, root)) is not None:
            found.append(DamagedEntry(city_paths.city_file(name, root),
                                      f"{damage}: dpe5g trace (make reproduce) traces the city again"))
    for view in sorted(n.removesuffix("_view") for n in names if n.endswith("_view")):
        try:
            city_paths.load_view(view, root)
        except DamagedEntry as err:
            found.append(err)
    return found


def write_stored(e: Experiment, arrays: dict, root: Path | None = None, code: dict | None = None) -> StoredRun:
    """Store ``e``'s results (``stored_fields``, as computed, compressed) with its config and their checksum.

    The ``.npz`` first, then the ``.json`` that makes the entry whole, each atomically: a reader between the two, or
    after a kill there, finds a damaged entry, named as such (``make reproduce`` again).

    Parameters
    ----------
    e : Experiment
        The experiment.
    arrays : dict
        Its results by name, trials on the leading axis.
    root : Path or None
        The store's folder; None: ``store_root()``.
    code : dict or None
        ``{"code_version": …, "commit": …}``, what computed them; None: today's (``git_commit``).

    Returns
    -------
    StoredRun
        The entry written.

    Raises
    ------
    ValueError
        When DPE5G_STORE is "off".
    """
    root = store_root() if root is None else root
    if root is None:
        raise ValueError("DPE5G_STORE is 'off': there is no results store to write")
    data = {k: np.asarray(arrays[k]) for k in stored_fields(e)}
    config = e.to_dict()
    for k in ("n_trials", "chunk_trials"):
        config.pop(k)
    meta = {"name": e.run.name, "config_key": e.config_key(), "config": jsonable(config), "n_trials": e.run.n_trials,
            "fields": {k: [str(v.dtype), list(v.shape[1:])] for k, v in data.items()},
            **(code or {"code_version": code_version(), "commit": git_commit()}), "numerics": numerics(),
            "arrays_sha256": arrays_digest(data)}
    stem = f"{e.run.name}-{e.config_key()}"  # (names may hold dots: no with_suffix)
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_write(root / f"{stem}.npz", buf.getvalue())
    atomic_write(root / f"{stem}.json", (json.dumps(meta, indent=1) + "\n").encode())
    return StoredRun(root / f"{stem}.npz", meta)


#: what the results are computed from: where these differ from the checkout's commit, the tree is changed for
#: ``dpe5g reproduce`` (which then refuses to run unless told, ``code_changes``)
CODE_PATHS = ("dpe5g", "environment.txt", "pyproject.toml")


def _git(*args: str, root: Path) -> str:
    return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=True).stdout


def code_changes(root: Path | None = None) -> list[str]:
    """The files of ``CODE_PATHS`` that differ from the checkout's commit, untracked ones included.

    Parameters
    ----------
    root : pathlib.Path or None
        The repository's folder; None: the one holding this package.

    Returns
    -------
    list of str
        Their paths in the repository, sorted; empty where the code is the commit's, or outside git.
    """
    root = REPOSITORY if root is None else root
    try:
        out = _git("status", "--porcelain", "--untracked-files=all", "--", *CODE_PATHS, root=root)
    except (OSError, subprocess.CalledProcessError):
        return []
    return sorted({line[3:].split(" -> ")[-1] for line in out.splitlines() if line.strip()
                   and not line[3:].endswith((".pyc", "/"))})


def git_commit(root: Path | None = None) -> str | None:
    """The commit whose code computed a result: the checkout's, and a digest of its changes if it has any.

    Parameters
    ----------
    root : pathlib.Path or None
        The repository's folder; None: the one holding this package.

    Returns
    -------
    str or None
        The commit's hash; with "+diff.<12 hex digits>" where the files of ``CODE_PATHS`` differ from it (the
        SHA-256 of ``git diff HEAD`` over them and of every untracked file's name and bytes, ``code_changes``), so
        two results computed from the same changes say so; None outside git.
    """
    root = REPOSITORY if root is None else root
    try:
        head = _git("rev-parse", "HEAD", root=root).strip()
        changed = code_changes(root)
        if not changed:
            return head
        h = hashlib.sha256(_git("diff", "--binary", "HEAD", "--", *CODE_PATHS, root=root).encode())
    except (OSError, subprocess.CalledProcessError):
        return None
    tracked = set(_git("ls-files", "--", *changed, root=root).split())
    for name in (c for c in changed if c not in tracked):
        path = root / name
        h.update(name.encode() + b"\0" + (path.read_bytes() if path.is_file() else b"") + b"\0")
    return f"{head}+diff.{h.hexdigest()[:12]}"
