"""Keep the book's execution cache (jupyter-cache) from serving outputs of old code.

jupyter-cache keys a chapter on its own code cells only, so after an edit of ``dpe5g/`` the book would show the new
code (``literalinclude``) beside outputs computed by the old code.  Before every book build the Makefile runs

    python scripts/book_cache.py book/_build/.jupyter_cache dpe5g environment.txt

which hashes the bytes of every file under the given sources (folders recursively, ``__pycache__`` and ``*.pyc``
left out) and, when the hash differs from the one stored beside the cache (``<cache>.sources.sha256``), deletes the cache so that every chapter
is re-executed.  Any change counts, comments and docstrings included: re-executing is cheap where the Monte Carlo
cache (keyed on the code's syntax tree, see ``dpe5g.montecarlo``) still holds.  ``tests/test_book_cache.py`` builds
a one-page book, changes its module and shows the rebuilt page's output change (and that without this step it
would not).
"""

from __future__ import annotations

import argparse
import hashlib
import shutil
import sys
from pathlib import Path

STAMP_SUFFIX = ".sources.sha256"


def sources_digest(paths: list[Path]) -> str:
    """SHA-256 over the relative names and bytes of every file under ``paths`` (files or folders), sorted."""
    h = hashlib.sha256()
    for root in paths:
        if not root.exists():
            raise ValueError(f"source {str(root)!r} does not exist")
        files = [root] if root.is_file() else sorted(
            p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc")
        for f in files:
            h.update(str(f.relative_to(root.parent)).encode() + b"\0")
            h.update(f.read_bytes() + b"\0")
    return h.hexdigest()


def sync(cache: Path, sources: list[Path]) -> bool:
    """Delete ``cache`` if ``sources`` changed since the digest stored in it; store the current digest.

    Returns True when the cache was cleared (or did not exist yet)."""
    digest = sources_digest(sources)
    stamp = cache.with_name(cache.name + STAMP_SUFFIX)
    cleared = not cache.exists() or not stamp.exists() or stamp.read_text().strip() != digest
    if cleared and cache.exists():
        shutil.rmtree(cache)
    stamp.parent.mkdir(parents=True, exist_ok=True)
    stamp.write_text(digest + "\n")
    return cleared


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cache", type=Path, help="the jupyter-cache folder (book/_build/.jupyter_cache)")
    ap.add_argument("sources", type=Path, nargs="+", help="files and folders whose change invalidates it")
    args = ap.parse_args(argv)
    try:
        cleared = sync(args.cache, args.sources)
    except (ValueError, OSError) as exc:
        print(f"book_cache: {exc}", file=sys.stderr)
        return 2
    if cleared:
        print(f"book_cache: {' '.join(map(str, args.sources))} changed (or no cache yet): every chapter will be "
              "re-executed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
