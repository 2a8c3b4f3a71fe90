"""The results on disk, in two tiers.

1. The results store (``figures/trials``, committed): per-trial results of every experiment the book and the
   figures read, keyed by the config (``Experiment.config_key``), each entry recording the code that computed it;
   ``verify`` recomputes a sample of its trials against today's code, ``dpe5g reproduce`` rewrites it.
2. The cache (``.cache/montecarlo``): one folder per experiment and code version (``<cache>/<name>-<key>``), one
   ``.npz`` per chunk of trials, every file written atomically (temporary file + rename), so an interrupted run
   resumes where it stopped and ends with results identical to an uninterrupted one; the chunks of a run at more
   SNRs, sliced to the SNRs asked for; and the figures' payloads (``payload_path``), keyed by the whole package.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from ._io import atomic_write, remove_stale_temporaries
from .experiment import Experiment, code_digest, code_version, numerics
from .results import Results

#: default cache directory: ``.cache/montecarlo`` next to the package (the repository root for an editable install);
#: the environment variable DPE5G_CACHE overrides it.
DEFAULT_CACHE = Path(__file__).resolve().parent.parent / ".cache" / "montecarlo"

def cache_root(cache: str | os.PathLike | None = None) -> Path:
    """The cache's root directory: the argument, else DPE5G_CACHE, else ``DEFAULT_CACHE``."""
    return Path(cache or os.environ.get("DPE5G_CACHE") or DEFAULT_CACHE)


def cache_dir(e: Experiment, cache: str | os.PathLike | None = None) -> Path:
    """The experiment's cache directory: ``<cache root>/<name>-<key>`` (``cache_root``)."""
    return cache_root(cache) / f"{e.run.name}-{e.key()}"


class ChunkCache:
    """One experiment's results on disk: ``cache_dir(e, cache)`` holds ``experiment.json`` (the config without the
    trial counts, and the key) and one ``.npz`` per chunk of ``chunk_trials`` trials.  Every file is written
    atomically (temporary file + rename), so a killed run leaves whole chunks and at most a stale ``*.tmp``, which
    ``open`` removes (not another live process's: two processes may fill one cache, ``warm``); ``missing`` lists the
    chunks still to compute (resume), ``load`` concatenates them all."""

    def __init__(self, e: Experiment, cache: str | os.PathLike | None = None):
        self.experiment = e
        self.dir = cache_dir(e, cache)
        self.chunks = [(s, min(s + e.run.chunk_trials, e.run.n_trials)) for s in range(0, e.run.n_trials, e.run.chunk_trials)]

    def path(self, start: int, stop: int) -> Path:
        return self.dir / f"trials-{start:07d}-{stop:07d}.npz"

    def open(self) -> "ChunkCache":
        """Create the directory and its metadata; remove temporary files a killed run left (their chunks are
        recomputed).  A root that is not a writable folder is a ``ValueError`` naming where it came from (the
        argument, DPE5G_CACHE or the default)."""
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            remove_stale_temporaries(self.dir)
            meta = self.dir / "experiment.json"
            if not meta.exists():
                d = self.experiment.to_dict()
                d.pop("n_trials")
                d.pop("chunk_trials")
                atomic_write(meta, json.dumps({"key": self.dir.name.rsplit("-", 1)[1], "experiment": d}, indent=1,
                                              default=str).encode())
        except OSError as err:
            root = self.dir.parent
            source = (f"DPE5G_CACHE={os.environ['DPE5G_CACHE']}" if os.environ.get("DPE5G_CACHE")
                      and root == Path(os.environ["DPE5G_CACHE"]) else f"the Monte Carlo cache {root}")
            raise ValueError(f"{source}: cannot write there ({err.strerror or err}); it must be a writable "
                             f"folder") from None
        return self

    def missing(self) -> list[tuple[int, int]]:
        return [c for c in self.chunks if not self.path(*c).exists()]

    def save(self, start: int, stop: int, arrays: dict) -> None:
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write(self.path(start, stop), buf.getvalue())

    def load(self, names) -> dict:
        parts = [np.load(self.path(*c)) for c in self.chunks]
        return {k: np.concatenate([p[k] for p in parts]) for k in names}


#: chunk arrays without an SNR axis (every other array is (T, S, ...)); ``snr_superset_runs`` slices the others
PER_TRIAL_FIELDS = ("ue_xyz", "clock_bias_s", "bs_index", "los")


def snr_superset_runs(e: Experiment, cache: str | os.PathLike | None = None) -> list[tuple[ChunkCache, list[int]]]:
    """Cached runs of ``e`` at more SNRs: experiments equal to ``e`` in every field but the name and ``snrs_db``,
    whose SNRs include all of ``e``'s, with the same key (code, data and library versions).  Trial t's draws and its
    noise (drawn once, scaled to each SNR) do not depend on the SNR list, so such a run's chunk, sliced to ``e``'s
    SNRs, is ``e``'s chunk (``tests/test_engine.py`` computes both).  Returns [(its cache, index of each of
    ``e``'s SNRs in its list)]."""
    if e.links.snr_mode == "link_budget":
        return []
    root = cache_root(cache)
    mine = json.loads(json.dumps(e.to_dict(), default=str))
    out = []
    for meta in sorted(root.glob("*/experiment.json")) if root.is_dir() else []:
        try:
            d = json.loads(meta.read_text())["experiment"]
        except (OSError, ValueError, KeyError):
            continue  # a folder being written, or not ours: not a source
        if not isinstance(d, dict) or set(d) != set(mine) - {"n_trials", "chunk_trials"}:
            continue
        if any(d[k] != mine[k] for k in d if k not in ("name", "snrs_db")):
            continue
        snrs = [float(v) for v in d["snrs_db"]]
        if tuple(snrs) == tuple(e.links.snrs_db) or not set(e.links.snrs_db) <= set(snrs):
            continue
        other = e.replace(name=str(d["name"]), snrs_db=tuple(snrs))
        if cache_dir(other, cache) == meta.parent:  # the same code, data and versions
            out.append((ChunkCache(other, cache), [snrs.index(v) for v in e.links.snrs_db]))
    return out


def sliced_chunk(path: Path, snr_index: list[int]) -> dict:
    """A chunk of a run at more SNRs, its (T, S, ...) arrays restricted to the SNRs ``snr_index``."""
    with np.load(path) as z:
        return {k: z[k] if k in PER_TRIAL_FIELDS else np.take(z[k], snr_index, axis=1) for k in z.files}


def payload_path(fig_id: str, trials: int | None = None, cache=None) -> Path:
    """Where ``figures.compute`` keeps the payload of ``fig_id`` (with ``trials``):
    ``<cache root>/payloads/<id>-<key>.json`` beside the Monte Carlo results (``cache_root``).  The key hashes the
    figure id, the trial count, the code of every module of the package (``experiment.code_digest``: docstrings and
    comments left out), its data files, the numerical libraries' versions and the results store's content
    (``store_digest``): everything a payload is computed from, so a stored payload is exactly what computing it
    again would give, and any change of code or of the store computes it anew."""
    here = Path(__file__).resolve().parent
    h = hashlib.sha256(json.dumps([fig_id, trials, numerics()], sort_keys=True).encode())
    for path in sorted(here.glob("*.py")):
        h.update(path.name.encode() + code_digest(path))
    for path in sorted(p for p in (here / "data").rglob("*") if p.is_file()):
        h.update(path.name.encode() + path.read_bytes())
    h.update(store_digest().encode())
    return cache_root(cache) / "payloads" / f"{fig_id}-{h.hexdigest()[:16]}.json"


def load_payload(fig_id: str, trials: int | None = None, cache=None) -> dict | None:
    """The stored payload of ``fig_id`` (``payload_path``), None when this code has not computed it."""
    path = payload_path(fig_id, trials, cache)
    return json.loads(path.read_text()) if path.exists() else None


def save_payload(fig_id: str, trials: int | None, payload: dict, cache=None) -> dict:
    """Store a payload (``payload_path``, written atomically) as JSON (``jsonable``); returns what was stored."""
    payload = jsonable(payload)
    atomic_write(payload_path(fig_id, trials, cache), json.dumps(payload).encode())
    return payload


def jsonable(x):
    """x with NumPy and JAX arrays and scalars turned into lists and Python numbers, recursively."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jax.Array)):
        return jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer, int)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x)
    return x


# ---- the results store (tier 1) ----------------------------------------------------------------------------------

#: the committed results store; DPE5G_STORE names another folder, or "off" to compute everything (tier 2 only)
STORE_DIR = Path(__file__).resolve().parent.parent / "figures" / "trials"
def store_root() -> Path | None:
    """The results store's folder: DPE5G_STORE if set ("off": None, no store), else ``STORE_DIR``."""
    env = os.environ.get("DPE5G_STORE")
    if env == "off":
        return None
    return Path(env) if env else STORE_DIR


def store_digest() -> str:
    """SHA-256 of the results store's files (names and bytes; "off" when there is none): what the payloads of
    ``payload_path`` read besides the code."""
    root = store_root()
    if root is None or not root.is_dir():
        return "off"
    h = hashlib.sha256()
    for path in sorted(p for p in root.iterdir() if p.suffix in (".npz", ".json")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def stored_fields(e: Experiment) -> tuple[str, ...]:
    """The fields of ``Results`` an entry of ``e`` holds: all of them (the OTDoA fields where ``e`` runs OTDoA)."""
    return Results.FIELDS + (Results.OTDOA_FIELDS if e.receiver.otdoa else ())


@dataclass(frozen=True)
class StoredRun:
    """One entry of the results store: ``<name>-<config key>.npz`` (the arrays as computed, float64 included,
    trials on the leading axis; compressed) and ``.json`` beside it (``meta``: name, config, n_trials, fields, code
    version and commit)."""

    npz: Path
    meta: dict

    @property
    def n_trials(self) -> int:
        return int(self.meta["n_trials"])

    def load(self, n_trials: int | None = None, trials=None) -> dict:
        """The stored arrays of trials 0 … n_trials-1 (or of the trial indices ``trials``)."""
        idx = slice(0, n_trials) if trials is None else np.asarray(trials)
        with np.load(self.npz) as z:
            return {k: z[k][idx] for k in z.files}


def stored(e: Experiment, root: Path | None = None) -> StoredRun | None:
    """The store's entry for ``e`` (same config key, at least ``e.run.n_trials`` trials), None if it holds none
    or the store is off.  Trial t depends only on the config, the seed and t, so an entry of N trials serves
    any run of n ≤ N."""
    root = store_root() if root is None else root
    if root is None or not root.is_dir():
        return None
    for meta_path in sorted(root.glob(f"*-{e.config_key()}.json")):
        meta = json.loads(meta_path.read_text())
        npz = meta_path.with_suffix(".npz")
        if npz.exists() and int(meta["n_trials"]) >= e.run.n_trials:
            return StoredRun(npz, meta)
    return None


def write_stored(e: Experiment, arrays: dict, root: Path | None = None, code: dict | None = None) -> StoredRun:
    """Store ``e``'s results (``stored_fields``, as computed, compressed) with its config and the code version that
    computed them (``code`` overrides ``{"code_version": …, "commit": …}``); the ``.npz`` first, then the ``.json``
    that makes the entry visible, each atomically."""
    root = store_root() if root is None else root
    if root is None:
        raise ValueError("DPE5G_STORE is 'off': there is no results store to write")
    data = {k: np.asarray(arrays[k]) for k in stored_fields(e)}
    config = e.to_dict()
    for k in ("n_trials", "chunk_trials"):
        config.pop(k)
    meta = {"name": e.run.name, "config_key": e.config_key(), "config": jsonable(config), "n_trials": e.run.n_trials,
            "fields": {k: [str(v.dtype), list(v.shape[1:])] for k, v in data.items()},
            **(code or {"code_version": code_version(), "commit": git_commit()}), "numerics": numerics()}
    stem = f"{e.run.name}-{e.config_key()}"  # (names may hold dots: no with_suffix)
    buf = io.BytesIO()
    np.savez_compressed(buf, **data)
    atomic_write(root / f"{stem}.npz", buf.getvalue())
    atomic_write(root / f"{stem}.json", (json.dumps(meta, indent=1) + "\n").encode())
    return StoredRun(root / f"{stem}.npz", meta)


def git_commit() -> str | None:
    """The checkout's commit (with "+changes" when its tracked files differ from it), None outside git."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")
