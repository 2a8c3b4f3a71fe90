"""Atomic file writes shared by the figure build, the Monte Carlo cache and the CLI."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_target(path):
    """Yield a temporary path beside ``path`` (``.<name>.…tmp``) to write to; on success rename it to ``path``, so a
    reader never sees a partial file and an existing file is never left half-overwritten; on failure remove it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (``atomic_target``)."""
    with atomic_target(path) as tmp:
        tmp.write_bytes(data)
