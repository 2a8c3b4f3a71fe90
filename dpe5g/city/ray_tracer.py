"""Sionna RT as this package runs it: the LLVM its CPU backend needs, the versions of its stack, and its one call.

Needs ``sionna-rt`` (pinned in environment.txt) and, for Dr.Jit's CPU backend, LLVM ≥ 16: Debian's ``libllvm19``.
The call (``solve_paths``) builds Sionna RT's default ``PathSolver()``, which does not promise the same paths from the
same seed (``PathSolver(deterministic=True)`` would, with more memory): ``dataset.compare_links`` holds a re-trace
of the stored city to tolerances.
Units: metres, dBm.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import re
import subprocess
import sys
from functools import lru_cache
from importlib.metadata import version
from pathlib import Path

import numpy as np

from ..common.errors import Failure

#: where ``llvm_library`` looks for libLLVM when DRJIT_LIBLLVM_PATH is not set (Debian's libllvm19 first)
LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*", "/usr/lib/aarch64-linux-gnu/libLLVM.so.19*",
              "/usr/lib/llvm-19/lib/libLLVM*.so*", "/usr/lib/*/libLLVM.so.1[6-9]*", "/usr/lib/*/libLLVM-1[6-9].so")


#: the oldest LLVM that Dr.Jit's CPU backend runs on: with LLVM 15 it aborts the process ("LLVM ERROR: Cannot select")
MIN_LLVM = 16

#: what ``check_llvm`` runs in a subprocess: a min/max through Dr.Jit's CPU backend, where LLVM 15 aborts
LLVM_PROBE = ("import drjit as dr\nfrom drjit.llvm import Float\nx = Float([1.0, 2.0, 3.0])\n"
              "dr.eval(dr.minimum(x, 1.5) + dr.maximum(x, 2.5))\n")


def llvm_library() -> str:
    """The libLLVM that Dr.Jit's CPU backend loads, checked (``check_llvm``): DRJIT_LIBLLVM_PATH if set, else the first
    of ``LLVM_GLOBS``; and the tracer's packages checked installed (``check_packages``).

    Returns
    -------
    str
        The library's path (also set in DRJIT_LIBLLVM_PATH, which Dr.Jit reads when it is imported); "" in a process
        that traces on CUDA (``traces_on_cuda``), which needs none.

    Raises
    ------
    errors.Failure
        When sionna-rt is missing, or no usable libLLVM is found: one line naming the package to install.
    """
    check_packages()
    if traces_on_cuda():
        return ""  # (Dr.Jit's CUDA backend needs no LLVM)
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path and not os.path.exists(path):
        raise Failure(f"DRJIT_LIBLLVM_PATH={path}: no such file (unset it, or name libLLVM.so.19.1)")
    if not path:
        found = sorted(p for g in LLVM_GLOBS for p in glob.glob(g))
        if not found:
            raise Failure("ray tracing needs LLVM 19 for Dr.Jit's CPU backend: apt-get install libllvm19 "
                               "(or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version 16 or later)")
        path = found[0]
    check_llvm(os.path.realpath(path))
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def check_packages() -> None:
    """The ray tracer's Python packages (sionna-rt, which brings mitsuba and drjit) are installed.

    Raises
    ------
    errors.Failure
        Naming the one to install (its pin is in environment.txt); everything that does not trace works without it.
    """
    for module, package in (("sionna", "sionna-rt"), ("mitsuba", "sionna-rt"), ("drjit", "sionna-rt"),
                            ("sionna.rt", "sionna-rt")):
        if not _installed(module):
            raise Failure(f"ray tracing needs {package} (its module {module} is missing): pip install the {package} "
                          "pinned in environment.txt; nothing else needs it")


def _installed(module: str) -> bool:
    """Whether ``module`` (a top-level name, or one subpackage of it) is installed, found without importing it
    (``sionna``'s ``__init__`` imports Sionna RT, which loads Dr.Jit)."""
    top, _, sub = module.partition(".")
    spec = importlib.util.find_spec(top)
    if spec is None or not sub:
        return spec is not None
    return any((Path(folder) / sub / "__init__.py").is_file() for folder in spec.submodule_search_locations or ())


@lru_cache(maxsize=8)
def check_llvm(path: str) -> None:
    """The libLLVM at ``path`` runs Dr.Jit's CPU backend: a version of ``MIN_LLVM`` or later by its file name, and
    ``LLVM_PROBE`` run in a subprocess on it (an unusable library aborts that process, never this one).  Once per
    library and process.

    Parameters
    ----------
    path : str
        The library, its links resolved.

    Raises
    ------
    errors.Failure
        Naming the library, what was wrong and the package to install.
    """
    remedy = "apt-get install libllvm19 and unset DRJIT_LIBLLVM_PATH (or name a libLLVM.so of version 16 or later)"
    m = re.search(r"LLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    if m and int(m.group(1)) < MIN_LLVM:
        raise Failure(f"{path}: LLVM {m.group(1)}, but Dr.Jit's CPU backend needs LLVM {MIN_LLVM} or later: {remedy}")
    try:
        r = subprocess.run([sys.executable, "-c", LLVM_PROBE], env={**os.environ, "DRJIT_LIBLLVM_PATH": path},
                           capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        raise Failure(f"{path}: Dr.Jit's CPU backend did not start on it within 300 s: {remedy}") from None
    if r.returncode != 0:
        why = next((line.strip() for line in r.stderr.splitlines() if "LLVM" in line or "Unable" in line),
                   f"exit code {r.returncode}")
        raise Failure(f"{path}: Dr.Jit's CPU backend cannot run on it ({why[:200]}): {remedy}")


#: the ray tracer's backends, each a Mitsuba variant: Dr.Jit's CPU backend on LLVM, and its CUDA backend on an NVIDIA
#: GPU; "auto" is Sionna RT's own choice when it is imported: CUDA where a GPU answers, else LLVM
BACKENDS = {"llvm": "llvm_ad_mono_polarized", "cuda": "cuda_ad_mono_polarized"}


def use_backend(backend: str = "auto") -> str:
    """Trace on ``backend`` in this process: Mitsuba's variant set before Sionna RT is imported (which would
    otherwise choose it), or checked where it is set already.

    Parameters
    ----------
    backend : str
        "auto", or a key of ``BACKENDS``.

    Returns
    -------
    str
        The Mitsuba variant the process traces on.

    Raises
    ------
    ValueError
        An unknown backend.
    errors.Failure
        In one line: "cuda" where Dr.Jit finds no CUDA device, or a process that already traces on another backend.
    """
    if backend != "auto" and backend not in BACKENDS:
        raise ValueError(f"backend must be 'auto' or one of {', '.join(BACKENDS)}, got {backend!r}")
    no_llvm = None
    check_packages()
    if backend != "cuda":
        try:
            llvm_library()  # (set before Dr.Jit loads: the LLVM backend reads it then)
        except Failure as err:
            if backend == "llvm":
                raise
            no_llvm = err  # ("auto": a GPU needs no LLVM)
    import mitsuba as mi  # (Sionna RT's renderer: loaded only to trace)

    wanted = [BACKENDS[backend]] if backend in BACKENDS else [BACKENDS["cuda"], BACKENDS["llvm"]]
    if mi.variant() is not None:
        if mi.variant() in wanted:
            return mi.variant()
        raise Failure(f"backend {backend}: this process already traces on {mi.variant()} (the backend is chosen once "
                      "per process, before anything is traced)")
    why = ""
    for variant in wanted:
        if variant == BACKENDS["llvm"] and no_llvm is not None:
            raise no_llvm
        try:
            mi.set_variant(variant)
            return variant
        except ImportError as err:  # (Dr.Jit: no CUDA device or driver, or no LLVM)
            why = " ".join(str(err).split())[:200]
    if backend == "cuda":
        raise Failure(f"backend cuda: Dr.Jit finds no CUDA device here ({why}); backend llvm traces on the CPU")
    raise Failure(f"backend {backend}: Dr.Jit cannot start {wanted[-1]} here ({why})")


def traces_on_cuda() -> bool:
    """Whether this process traces on Dr.Jit's CUDA backend (Mitsuba imported, its variant ``BACKENDS["cuda"]``).

    Returns
    -------
    bool
    """
    mi = sys.modules.get("mitsuba")
    return mi is not None and mi.variant() == BACKENDS["cuda"]


def library_versions() -> dict:
    """The versions of the ray tracer's stack (sionna-rt, mitsuba, drjit) and the libLLVM it runs on (none on CUDA).

    Returns
    -------
    dict
    """
    out = {p: version(p) for p in ("sionna-rt", "mitsuba", "drjit")}
    return out if traces_on_cuda() else out | {"libllvm": os.path.basename(llvm_library())}


#: slots per UE in the path solver's table of specular chains already found (``solve_paths``)
CHAIN_SLOTS_PER_UE = 100_000


def solve_paths(scene, bs_xyz, ue_xyz, spec):
    """Sionna RT's paths from every BS ``bs_xyz`` to every UE ``ue_xyz``: the solver call of ``trace_links`` and
    ``city_view.example_paths``.

    The solver marks a specular chain as found in a hash table per BS of max(10⁶, ``max_num_paths_per_src``) slots
    whose keys are (chain, UE); a new chain whose slot is taken is dropped.  At 250 UEs a call the default table
    dropped the first path of 1.9 % of the links (16 of 854 measured), so the table is made ``CHAIN_SLOTS_PER_UE``
    slots per UE (at least 10⁶), which keeps a UE's paths nearly independent of the UEs traced beside it.

    Parameters
    ----------
    scene : sionna.rt.Scene
        The scene (``load_scene``); its transmitters and receivers are replaced.
    bs_xyz : float (B, 3)
        Transmitters, metres.
    ue_xyz : float (U, 3)
        Receivers, metres.
    spec : city_trace.CitySpec
        The solver's settings: LoS, specular reflections and, where ``spec`` turns them on, wedge and edge diffraction,
        diffuse reflection (off the materials' scattering coefficient, ``load_scene``) and refraction, up to
        ``spec.max_depth`` interactions, ``spec.samples_per_src`` rays per BS, the solver seeded by ``spec.seed``.

    Returns
    -------
    sionna.rt.Paths
    """
    import mitsuba as mi  # (Sionna RT: loaded only to trace)
    import sionna.rt as rt  # (Sionna RT: loaded only to trace)
    from sionna.rt.path_solvers.sb_candidate_generator import SBCandidateGenerator  # (Sionna RT: loaded only to trace)

    for name in list(scene.transmitters) + list(scene.receivers):
        scene.remove(name)
    for b, p in enumerate(np.asarray(bs_xyz, float)):
        scene.add(rt.Transmitter(f"bs{b}", position=mi.Point3f(*map(float, p)), power_dbm=spec.power_dbm))
    for u, p in enumerate(np.asarray(ue_xyz, float).reshape(-1, 3)):
        scene.add(rt.Receiver(f"ue{u}", position=mi.Point3f(*map(float, p))))
    default = SBCandidateGenerator.MIN_SPEC_COUNT_SIZE
    SBCandidateGenerator.MIN_SPEC_COUNT_SIZE = max(default, CHAIN_SLOTS_PER_UE * len(scene.receivers))
    try:
        return rt.PathSolver()(scene, max_depth=spec.max_depth, samples_per_src=spec.samples_per_src, los=True,
                               specular_reflection=True, diffuse_reflection=spec.diffuse_reflection,
                               refraction=spec.refraction, diffraction=spec.diffraction,
                               edge_diffraction=spec.edge_diffraction, seed=spec.seed)
    finally:
        SBCandidateGenerator.MIN_SPEC_COUNT_SIZE = default


