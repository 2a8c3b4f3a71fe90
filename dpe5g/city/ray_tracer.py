"""Sionna RT as this package runs it: the LLVM its CPU backend needs, the versions of its stack, and its one call.

Needs ``sionna-rt`` (pinned in environment.txt) and, for Dr.Jit's CPU backend, LLVM ≥ 16: Debian's ``libllvm19``.
The call (``solve_paths``) builds Sionna RT's default ``PathSolver()``, which does not promise the same paths from the
same seed (``PathSolver(deterministic=True)`` would, with more memory): ``dataset.compare_links`` holds a re-trace
of the stored city to tolerances.
Units: metres, dBm.
"""

from __future__ import annotations

import glob
import os
from importlib.metadata import version

import numpy as np

from ..common.errors import Failure

#: where ``llvm_library`` looks for libLLVM when DRJIT_LIBLLVM_PATH is not set (Debian's libllvm19 first)
LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19*", "/usr/lib/aarch64-linux-gnu/libLLVM.so.19*",
              "/usr/lib/llvm-19/lib/libLLVM*.so*", "/usr/lib/*/libLLVM.so.1[6-9]*", "/usr/lib/*/libLLVM-1[6-9].so")


def llvm_library() -> str:
    """The libLLVM that Dr.Jit's CPU backend loads: DRJIT_LIBLLVM_PATH if set, else the first of ``LLVM_GLOBS``.

    Returns
    -------
    str
        The library's path (also set in DRJIT_LIBLLVM_PATH, which Dr.Jit reads when it is imported).

    Raises
    ------
    errors.Failure
        When none is found: one line naming the Debian package.
    """
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    if path and not os.path.exists(path):
        raise Failure(f"DRJIT_LIBLLVM_PATH={path}: no such file (unset it, or name libLLVM.so.19.1)")
    if not path:
        found = sorted(p for g in LLVM_GLOBS for p in glob.glob(g))
        if not found:
            raise Failure("ray tracing needs LLVM 19 for Dr.Jit's CPU backend: apt-get install libllvm19 "
                               "(or set DRJIT_LIBLLVM_PATH to a libLLVM.so of version 16 or later)")
        path = found[0]
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def library_versions() -> dict:
    """The versions of the ray tracer's stack (sionna-rt, mitsuba, drjit) and the libLLVM it runs on.

    Returns
    -------
    dict
    """
    return {p: version(p) for p in ("sionna-rt", "mitsuba", "drjit")} | {"libllvm": os.path.basename(llvm_library())}


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


