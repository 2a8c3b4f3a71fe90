"""``jupyter-book build`` with Sphinx's parallel read, so that the chapters execute BOOK_JOBS at a time.

Jupyter Book 1's command line builds with one process; Sphinx reads documents in parallel when asked to and when
every extension declares itself parallel-read safe.  myst-nb, which executes each chapter as Sphinx reads it, the
theme, sphinxcontrib-bibtex and the book's extension do; three small extensions are safe but say nothing
(``PARALLEL_SAFE``), and without a declaration Sphinx reads serially and warns, an error under -W.  This script
declares them, passes ``jobs`` to Jupyter Book's own build function and runs its command line unchanged (``make
book``: ``python scripts/build_book.py build . --config ... --toc ...``).  BOOK_JOBS defaults to the number of CPUs.

With more than one job each chapter's kernel computes on one thread (``one_thread_per_kernel``): the engine's batch
threads, XLA's thread pool and OpenBLAS's are each sized to every CPU, and OpenBLAS's threads wait for work by
spinning, so two kernels in NumPy's lstsq (``bounds``) at once made no progress for minutes on 2 CPUs.
"""

from __future__ import annotations

import importlib
import json
import os
import sys
from pathlib import Path

import jupyter_book.sphinx as jb_sphinx
import sphinx.builders
from jupyter_book.cli.main import main

JOBS = int(os.environ.get("BOOK_JOBS", os.cpu_count() or 1))
#: extensions that are parallel safe without saying so: sphinx-multitoc-numbering replaces the method that numbers
#: the toctree, which Sphinx calls in the main process on the merged environment; sphinx-mathjax-offline sets a
#: config value and copies MathJax when the build finishes; sphinx-jupyterbook-latex adds nodes and transforms that
#: act in the LaTeX builder only.  None keeps state per document.
PARALLEL_SAFE = ("sphinx_multitoc_numbering", "sphinx-mathjax-offline", "sphinx_jupyterbook_latex")


def declare_parallel_safe(name: str) -> None:
    """Wrap extension ``name``'s ``setup`` so that it returns the parallel-safe declaration it lacks."""
    module = importlib.import_module(name)
    setup = module.setup

    def safe_setup(app):
        return (setup(app) or {}) | {"parallel_read_safe": True, "parallel_write_safe": True}

    module.setup = safe_setup


def chapter_seconds() -> dict:
    """Each chapter's execution time at the last recorded fresh check (benchmarks/fresh_check.json), by docname."""
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "fresh_check.json"
    try:
        return {f"chapters/{k}": float(v) for k, v in json.loads(path.read_text())["chapters_s"].items()}
    except (OSError, ValueError, KeyError):
        return {}


def longest_first(docnames, nproc, maxbatch=10):
    """Sphinx's parallel read in chunks of one document each, the longest-running chapters started first.

    Sphinx's own ``make_chunks`` cuts 17 documents into two chunks in name order, and one of them holds every chapter
    but two, so the chapters ran one after another.  With one per chunk a worker takes the next document as soon as
    it is done.  Sphinx (7.4, ``ParallelTasks``) starts the first ``nproc`` tasks as they are added and the others last
    in, first out; so the ``nproc`` longest chapters (by ``chapter_seconds``) go first and the rest shortest first.
    Measured on a fresh clone: chapter 3 (70 s) started last kept the build waiting for it alone.
    """
    cost = chapter_seconds()
    order = sorted(docnames, key=lambda d: -cost.get(d, 0.0))
    head, rest = order[:nproc], sorted(order[nproc:], key=lambda d: cost.get(d, 0.0))
    return [[d] for d in head + rest]


def one_thread_per_kernel() -> None:
    """Environment for the kernels that the build starts: the engine computes one batch at a time (DPE5G_WORKERS),
    OpenBLAS (NumPy's linear algebra) uses one thread and XLA runs each program on the calling thread
    (``--xla_cpu_multi_thread_eigen=false``)."""
    for name in ("DPE5G_WORKERS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_multi_thread_eigen" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " --xla_cpu_multi_thread_eigen=false").strip()


def build_sphinx(*args, _build=jb_sphinx.build_sphinx, **kwargs):
    """Jupyter Book's ``build_sphinx`` with ``jobs=JOBS`` (its command line always passes None, one process)."""
    kwargs["jobs"] = JOBS
    return _build(*args, **kwargs)


if __name__ == "__main__":
    if JOBS > 1:
        one_thread_per_kernel()
    for ext in PARALLEL_SAFE:
        declare_parallel_safe(ext)
    sphinx.builders.make_chunks = longest_first
    jb_sphinx.build_sphinx = build_sphinx
    sys.exit(main())
