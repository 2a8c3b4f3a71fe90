"""The XLA backend optimisation level that importing dpe5g asks for (``dpe5g.XLA_OPT_LEVEL``) is added to XLA_FLAGS
unless they set one.  That it changes no result (the engines give the same bits at XLA's own default) is checked by
``benchmarks/bench_xla_level.py``: it compiles every engine twice in fresh processes, a benchmark's cost."""

import pytest

import dpe5g


def test_the_flag_is_added_unless_set():
    assert dpe5g.xla_flags("", None) == f"--xla_backend_optimization_level={dpe5g.XLA_OPT_LEVEL}"
    assert dpe5g.xla_flags("--xla_foo=1", "3") == "--xla_foo=1 --xla_backend_optimization_level=3"
    assert dpe5g.xla_flags("--xla_backend_optimization_level=2", "1") == "--xla_backend_optimization_level=2"
    assert dpe5g.xla_flags("--xla_foo=1", "xla") == "--xla_foo=1"
    with pytest.raises(ValueError, match="DPE5G_XLA_OPT_LEVEL must be one of 0, 1, 2, 3 or xla, got '7'"):
        dpe5g.xla_flags("", "7")
