"""Execute one chapter of the book on its own and write it as an executed notebook (what ``make chapter`` runs).

    python scripts/run_chapter.py 05            # chapters/05_*.md -> book/_build/chapters/05_rmse_vs_snr.ipynb
    python scripts/run_chapter.py 05 --smoke    # DPE5G_SMOKE=1: fewer Monte Carlo trials, for a quick look
    python scripts/run_chapter.py 05 --which    # chapters/05_rmse_vs_snr.md (what ``make lab CH=05`` opens)

The chapter (a MyST-markdown notebook) is read with jupytext and executed with nbclient in the ``chapters/``
folder, the same kernel the book uses; no network is needed.  The Monte Carlo results are shared with the book and
``make figures`` through the cache in ``.cache/montecarlo``, so a chapter whose experiments are cached runs in
seconds.  A number the chapter's prose glues is shown in its cell's output (``registry.glue_value``: no book is
building), and so is each figure.  Prints each cell's progress and the total run time; a failing cell prints its error and exits 1, a bad
chapter name exits 2.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CHAPTERS = ROOT / "chapters"


def find_chapter(name: str) -> Path:
    """``chapters/<name>*.md`` for a number ("05", "5") or a file stem; ValueError naming the choices otherwise."""
    stems = sorted(p.stem for p in CHAPTERS.glob("*.md"))
    key = name.strip()
    if key.isdigit():
        key = f"{int(key):02d}_"
    hits = [s for s in stems if s.startswith(key) or s == name]
    if len(hits) != 1:
        raise ValueError(f"CH={name!r} names no single chapter; choose one of: {', '.join(stems)}")
    return CHAPTERS / f"{hits[0]}.md"


def run(path: Path, out_dir: Path, smoke: bool) -> tuple[Path, float]:
    import jupytext
    from nbclient import NotebookClient

    nb = jupytext.read(path)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    if smoke:
        os.environ["DPE5G_SMOKE"] = "1"
    else:
        os.environ.pop("DPE5G_SMOKE", None)
    client = NotebookClient(nb, timeout=3600, kernel_name="python3", resources={"metadata": {"path": str(CHAPTERS)}})
    n_code = sum(c.cell_type == "code" for c in nb.cells)
    done = 0
    t0 = time.perf_counter()
    with client.setup_kernel():
        for i, cell in enumerate(nb.cells):
            if cell.cell_type != "code":
                continue
            done += 1
            print(f"\r{path.stem}: cell {done}/{n_code}, {time.perf_counter() - t0:6.0f} s", end="", flush=True)
            client.execute_cell(cell, i)
    elapsed = time.perf_counter() - t0
    print()
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / f"{path.stem}{'.smoke' if smoke else ''}.ipynb"
    import nbformat

    nbformat.write(nb, out)
    return out, elapsed


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("chapter", help="chapter number (05) or file stem (05_rmse_vs_snr)")
    ap.add_argument("--smoke", action="store_true", help="DPE5G_SMOKE=1: fewer Monte Carlo trials")
    ap.add_argument("--which", action="store_true", help="print the chapter's file (make lab opens it) and exit")
    ap.add_argument("--out", type=Path, default=ROOT / "book" / "_build" / "chapters",
                    help="folder for the executed notebook (default: book/_build/chapters)")
    args = ap.parse_args(argv)
    try:
        path = find_chapter(args.chapter)
    except ValueError as exc:
        print(f"run_chapter: {exc}", file=sys.stderr)
        return 2
    if args.which:
        print(path.relative_to(ROOT))
        return 0
    from nbclient.exceptions import CellExecutionError

    try:
        out, elapsed = run(path, args.out, args.smoke)
    except CellExecutionError as exc:
        print(f"\nrun_chapter: {path.name} failed:\n{exc}", file=sys.stderr)
        return 1
    print(f"{path.name}{' (smoke)' if args.smoke else ''} executed in {elapsed:.0f} s; wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
