"""Where the project keeps its files: the repository, the committed results store, the committed figure baselines and
the Monte Carlo cache, each by its folder (a path relative to the repository, resolved from this file's place).

Every module that reads or writes one of them asks here, so a moved module cannot lose its way to the repository.
"""

from __future__ import annotations

import os
from pathlib import Path

#: the repository's folder: the one holding the package ``dpe5g`` (an editable install's checkout)
REPOSITORY = Path(__file__).resolve().parents[2]

#: the committed results store; DPE5G_STORE names another folder, or "off" to compute everything (tier 2 only)
STORE_DIR = REPOSITORY / "figures" / "trials"

#: the committed figure baselines (``dpe5g figures --update-baselines`` writes them)
BASELINE_DIR = REPOSITORY / "figures"

#: the Monte Carlo cache's default root (tier 2 of the results on disk); DPE5G_CACHE names another
DEFAULT_CACHE = REPOSITORY / ".cache" / "montecarlo"

#: the ray tracer's cache of traced batches of UEs (``city.trace_chunks``), so that a stopped trace resumes
TRACE_CACHE = REPOSITORY / ".cache" / "trace"


def store_root() -> Path | None:
    """The results store's folder.

    Returns
    -------
    Path or None
        DPE5G_STORE if set ("off": None, no store), else ``STORE_DIR``.

    Raises
    ------
    ValueError
        When DPE5G_STORE names something that is not a folder.
    """
    env = os.environ.get("DPE5G_STORE")
    if env == "off":
        return None
    if env and Path(env).exists() and not Path(env).is_dir():
        raise ValueError(f"DPE5G_STORE={env}: is not a folder (name a results store's folder, or 'off')")
    return Path(env) if env else STORE_DIR


def cities_dir() -> Path:
    """The traced cities' folder: ``cities/`` of the results store in use (DPE5G_STORE, else ``STORE_DIR``); with
    DPE5G_STORE "off", the committed store's (a city is never computed on the fly: only ``dpe5g trace`` traces one).

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        When DPE5G_STORE names something that is not a folder.
    """
    return (store_root() or STORE_DIR) / "cities"
