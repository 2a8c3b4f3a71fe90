"""dpe5g: reproducible companion to "5G Direct Position Estimation for Precise Localization in Dense Urban Area".

Modules are named after the paper's objects: ``nr`` (numerology, PRS), ``channel`` (TR 38.901 TDL, eqs. (1)–(2)),
``signal`` (eqs. (3)–(6)), ``correlogram`` (the LS CIR estimate both receivers share), ``dpe`` (eqs. (7)–(10)), ``otdoa``,
``deployment`` and ``scenario`` (Section III), ``montecarlo`` (Section IV), ``figures`` (one registered producer per
figure) and ``plots`` (their drawing).

Importing the package turns on JAX float64: ToAs are ~1e-6 s and must be resolved to ~1e-10 s, and the phases
k Δf τ reach hundreds of cycles, which float32 cannot carry to the precision the estimators need.

It also turns on JAX's persistent compilation cache in ``.cache/jax`` next to the package (the repository root for
an editable install; DPE5G_JAX_CACHE overrides the directory, "off" leaves JAX's setting alone), unless a directory
is already configured.  A compiled program is stored under a key of its code, shapes, options and the jax version,
so it changes no result; it saves the 10–30 s compile of each Monte Carlo engine in every later process (each
chapter of the book runs in its own).  Every program is stored, however quick its compile: a chapter re-executed
with a warm cache runs Chapter 3 in 40 s instead of 74 s, most of that in sub-second compiles.
"""

import os
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

_jax_cache = os.environ.get("DPE5G_JAX_CACHE", str(Path(__file__).resolve().parent.parent / ".cache" / "jax"))
if _jax_cache != "off" and not jax.config.jax_compilation_cache_dir:
    jax.config.update("jax_compilation_cache_dir", _jax_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

__version__ = "0.1.0"
