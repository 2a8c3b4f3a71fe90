"""dpe5g: reproducible companion to "5G Direct Position Estimation for Precise Localization in Dense Urban Area".

Subpackages follow the data flow, each module named after the paper's object it holds: ``phy`` (numerology and PRS,
the TDL channel, the signal model, propagation, deployments) → ``receivers`` (correlograms, the ML cost, DPE and its
searches, OTDoA, the NLoS-aware receivers) and ``city`` (the ray-traced city) → ``simulation`` (the Monte Carlo:
experiment, draws, trials, engine, cache, store, results) → ``bounds`` → ``studies`` (the book's experiments and their
statistics) → ``figures`` (the paper's figures and the book's tables) → ``cli``; ``common`` holds what all share.
The modules a user calls are importable from the top, ``from dpe5g import dpe, otdoa, cost, nr, signal, channel,
deployment, experiment, engine, results`` (``PUBLIC``, loaded on first use).

Importing the package turns on JAX float64: ToAs are ~1e-6 s and must be resolved to ~1e-10 s, and the phases
k Δf τ reach hundreds of cycles, which float32 cannot carry to the precision the estimators need.

It also turns on JAX's persistent compilation cache in ``.cache/jax`` next to the package (the repository root for
an editable install; DPE5G_JAX_CACHE overrides the directory, "off" leaves JAX's setting alone), unless a directory
is already configured.  A compiled program is stored under a key of its code, shapes, options and the jax version,
so it changes no result; it saves the 10–30 s compile of each Monte Carlo engine in every later process (each
chapter of the book runs in its own).  Every program is stored, however quick its compile: a chapter re-executed
with a warm cache runs the DPE chapter in 40 s instead of 74 s, most of that in sub-second compiles.

It also asks XLA for its backend optimisation level 1 (``XLA_OPT_LEVEL``) instead of its default, unless
DPE5G_XLA_OPT_LEVEL says otherwise ("0"–"3", or "xla" for XLA's own default) or XLA_FLAGS already sets the level:
measured on the 2-core CI machine, the truth-centred Fig. 9 engine compiles in 5.2 s instead of 9.5 s and runs as
fast, the book's engines compile in 245 s instead of 301 s, and a cold run of the tests (empty caches) takes 236 s
instead of 280 s.  The level changes no number: the engines' results are equal to the bit at both levels
(``benchmarks/bench_xla_level.py`` runs them in a process at XLA's default and compares), so it is not part of a cached
run's key.  XLA reads the flag when JAX first starts its backend: importing ``dpe5g`` after JAX has computed
anything leaves the level as it was.
"""

import importlib as _importlib
import os
import signal as _signal  # (not ``signal``: that name is the public module ``phy.signal``)
import time as _time
import sys
import warnings as _warnings
from pathlib import Path

#: when this process imported dpe5g (ns since the epoch): a source file changed later is not the code it runs
#: (``code_key.changed_since_import``)
IMPORTED_AT_NS = _time.time_ns()

#: the XLA backend optimisation level importing dpe5g asks for (see the module docstring); DPE5G_XLA_OPT_LEVEL overrides
XLA_OPT_LEVEL = 1


def xla_flags(flags: str, level: str | None) -> str:
    """XLA_FLAGS with the backend optimisation level ``level`` ("0"–"3"; None: ``XLA_OPT_LEVEL``; "xla": unchanged)
    added, unless ``flags`` sets it already."""
    level = str(XLA_OPT_LEVEL) if level is None else level.strip()
    if level not in ("0", "1", "2", "3", "xla"):
        raise ValueError(f"DPE5G_XLA_OPT_LEVEL must be one of 0, 1, 2, 3 or xla, got {level!r}")
    if level == "xla" or "xla_backend_optimization_level" in flags:
        return flags
    return f"{flags} --xla_backend_optimization_level={level}".strip()


def _cli_starting() -> bool:
    """Whether this import starts the ``dpe5g`` command line: ``python -m dpe5g …`` (sys.argv[0] is "-m" while
    Python locates the module) or the ``dpe5g`` script.  A bad setting read at import then ends as the CLI's own
    errors do, in one line and exit code 2, since the CLI's handler does not exist yet."""
    argv = getattr(sys, "argv", None) or [""]
    return argv[0] == "-m" or Path(argv[0]).name == "dpe5g"


def _interrupted_while_starting(signum, frame):
    """Ctrl-C or SIGTERM while the command line starts (importing JAX takes a second or two), before ``cli.main``
    installs its own handling: one line and exit code 130 (143 for SIGTERM), as at any later moment; nothing has
    been written yet."""
    word = "terminated" if signum == _signal.SIGTERM else "interrupted"
    sys.stderr.write(f"dpe5g: {word} while starting; nothing was written\n")
    os._exit(128 + int(signum))


if _cli_starting():
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
    _signal.signal(_signal.SIGTERM, _interrupted_while_starting)

try:
    os.environ["XLA_FLAGS"] = xla_flags(os.environ.get("XLA_FLAGS", ""), os.environ.get("DPE5G_XLA_OPT_LEVEL"))
except ValueError as exc:
    if not _cli_starting():
        raise
    print(f"dpe5g: error: {exc}", file=sys.stderr)
    raise SystemExit(2) from None

import jax  # noqa: E402  (after XLA_FLAGS)

jax.config.update("jax_enable_x64", True)

_jax_cache = os.environ.get("DPE5G_JAX_CACHE", str(Path(__file__).resolve().parent.parent / ".cache" / "jax"))
if _jax_cache != "off" and not jax.config.jax_compilation_cache_dir:
    jax.config.update("jax_compilation_cache_dir", _jax_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

__version__ = "0.1.0"

#: the modules a user calls, by their top-level name: ``from dpe5g import dpe`` loads ``dpe5g.receivers.dpe``
PUBLIC = {"nr": "phy.nr", "channel": "phy.channel", "signal": "phy.signal", "deployment": "phy.deployment",
          "cost": "receivers.cost", "dpe": "receivers.dpe", "otdoa": "receivers.otdoa",
          "experiment": "simulation.experiment", "engine": "simulation.engine", "results": "simulation.results"}

#: where the other modules of the flat layout (0.1.0 until the subpackages) went: still importable from the top, with a
#: DeprecationWarning naming the new place (``figures``, ``bounds``, ``studies`` and ``cli`` are the subpackages now)
MOVED = {"correlogram": "receivers.correlogram", "search_config": "receivers.search_config",
         "grid_search": "receivers.grid_search", "certified_search": "receivers.certified_search",
         "spline_bounds": "receivers.spline_boxes", "receiver": "receivers.receiver", "dpe_nlos": "receivers.dpe_nlos",
         "otdoa_nlos": "receivers.otdoa_nlos", "toa_fit": "receivers.toa_fit", "scenario": "phy.propagation",
         "ray_tracer": "city.ray_tracer", "city_trace": "city.trace", "city_paths": "city.dataset",
         "city_view": "city.view", "trial_draw": "simulation.trial_draw", "draw": "simulation.draw",
         "city_draw": "simulation.traced_draw", "trials": "simulation.trials", "cluster": "simulation.cluster",
         "code_key": "simulation.code_key", "chunk_cache": "simulation.chunk_cache", "store": "simulation.store",
         "verify": "simulation.verify", "nlos_bounds": "bounds.misspecified", "paper": "studies.paper",
         "readings": "studies.readings", "nlos_study": "studies.nlos", "city_study": "studies.city",
         "city_channel": "studies.city_channel", "city_errors": "studies.city_errors",
         "city_sensitivity": "studies.city_sensitivity", "intervals": "studies.intervals",
         "significance": "studies.significance", "catalog": "studies.catalog", "figure_data": "figures.data",
         "plots": "figures.plots", "result_plots": "figures.result_plots", "reuse_plots": "figures.result_plots",
         "city_plots": "figures.city_plots", "report": "figures.tables", "scene3d": "figures.scene3d",
         "errors": "common.errors", "locations": "common.locations"}


def __getattr__(name: str):
    """``PUBLIC``'s modules and the flat layout's ``MOVED`` ones, loaded on first use (PEP 562)."""
    if name in PUBLIC:
        return _importlib.import_module(f"{__name__}.{PUBLIC[name]}")
    if name in MOVED:
        _warnings.warn(f"dpe5g.{name} moved to dpe5g.{MOVED[name]}; import it from there", DeprecationWarning,
                      stacklevel=2)
        return _importlib.import_module(f"{__name__}.{MOVED[name]}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *PUBLIC})
