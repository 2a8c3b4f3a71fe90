"""dpe5g: reproducible companion to "5G Direct Position Estimation for Precise Localization in Dense Urban Area".

Modules are named after the paper's objects: ``nr`` (numerology, PRS), ``channel`` (TR 38.901 TDL, eqs. 1–2),
``signal`` (eqs. 3–4), ``figures`` (one registered producer per figure) and ``plots`` (their drawing).

Importing the package turns on JAX float64: ToAs are ~1e-6 s and must be resolved to ~1e-10 s, and the phases
k Δf τ reach hundreds of cycles, which float32 cannot carry to the precision the estimators need.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
