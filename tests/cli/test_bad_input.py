"""Bad input to the library's public entry points (issue 33): every function that takes a physical quantity answers
NaN, ±inf, a negative, zero, a huge value, a text, True/False and a value in the wrong unit with a ``ValueError``
that names the parameter, and a value in its range with a finite result, never a silent nonsense value.

Each row: the entry point as a function of the one value, the parameter's name, and its allowed range (inclusive);
hypothesis draws the values, from the classes above and from anywhere on the real line."""

import math

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dpe5g.phy import channel, deployment, propagation, signal
from dpe5g.receivers import search_config
from dpe5g.simulation import experiment

KEY = jax.random.PRNGKey(0)
TST = deployment.tst()

#: (name of the row, f(value), parameter named in the error, lo, hi)
ENTRY_POINTS = [
    ("los_probability", lambda v: propagation.los_probability(v), "d2d_m", 0.0, propagation.MAX_D2D_M),
    ("path_loss d2d", lambda v: propagation.path_loss_umi_db(v, 10.0, 1.5, 3e9, True), "d2d_m", 0.0, propagation.MAX_D2D_M),
    ("path_loss h_bs", lambda v: propagation.path_loss_umi_db(50.0, v, 1.5, 3e9, True), "h_bs_m", 1.5, 150.0),
    ("path_loss h_ut", lambda v: propagation.path_loss_umi_db(50.0, 10.0, v, 3e9, False), "h_ut_m", 1.0, 22.5),
    ("path_loss fc", lambda v: propagation.path_loss_umi_db(50.0, 10.0, 1.5, v, True), "fc_hz", 0.5e9, 100e9),
    ("clock_bias sigma", lambda v: propagation.clock_bias(KEY, v, 3.0, (4,)), "sigma_s", 0.0, 1e-6),
    ("clock_bias bound", lambda v: propagation.clock_bias(KEY, 5e-9, v, (4,)), "bound_sigmas", 0.1, 10.0),
    ("tdl_profile delay spread", lambda v: channel.tdl_profile("C", v).delays_s, "delay_spread_s",
     channel.MIN_DELAY_SPREAD_S, channel.MAX_DELAY_SPREAD_S),
    ("rms_delay_spread delays", lambda v: channel.rms_delay_spread([0.0, v], [1.0, 0.5]), "delays_s", 0.0, 1e6),
    ("rms_delay_spread powers", lambda v: channel.rms_delay_spread([0.0, 1e-7], [1.0, v]), "powers", 0.0, math.inf),
    ("snr", lambda v: signal.check_snr_db(v), "snr_db", -50.0, 100.0),
    ("nearest", lambda v: TST.nearest([v, 100.0], 3), "ue_xy", -1e6, 1e6),
    ("link budget fc", lambda v: propagation.LinkBudget(fc_hz=v).noise_dbm, "fc_hz", 0.5e9, 100e9),
    ("search half width", lambda v: search_config.SearchConfig(half_width_m=v).half_width_m, "half_width_m", 0.1,
     1000.0),
    ("experiment clock", lambda v: experiment.Scenario(clock_sigma_s=v).clock_sigma_s, "clock_sigma_s", 0.0, 1e-6),
    ("experiment delay spread", lambda v: experiment.Scenario(delay_spread_s=v).delay_spread_s, "delay_spread_s",
     channel.MIN_DELAY_SPREAD_S, channel.MAX_DELAY_SPREAD_S),
    ("experiment K", lambda v: experiment.Scenario(k_factor_db=v).k_factor_db, "k_factor_db", -30.0, 60.0),
    ("experiment prior", lambda v: experiment.Receiver(prior_scale_m=v).prior_scale_m, "prior_scale_m", 0.0, 1000.0),
    ("experiment snrs", lambda v: experiment.Links(snrs_db=(v,)).snrs_db, "snr_db", -50.0, 100.0),
    ("noise_variance", lambda v: signal.noise_variance(v, np.ones(8)), "snr_db", -50.0, 100.0),
    ("awgn", lambda v: np.abs(signal.awgn(KEY, (2, 8), v)), "variance", 0.0, 1e308),
]

#: values of every class the issue names; the wrong unit: nanoseconds, GHz, kilometres typed where the base unit is
#: meant (they fall outside the ranges, or are checked to be accepted as numbers when they do not)
CLASSES = [math.nan, math.inf, -math.inf, -5.0, -1e-12, 0.0, 1e300, -1e300, 5.0, 65.0, 3.0, 1e-300, "65e-9", "x",
           None, True, False, [1.0, math.nan]]
VALUES = st.one_of(st.sampled_from(CLASSES), st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-1e-5, 1e-5), st.floats(0.5e9, 2e11))


def _valid(v, lo, hi) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v <= hi)


def _check(row, v):
    name, f, param, lo, hi = row
    if _valid(v, lo, hi):
        out = np.asarray(f(v), dtype=float)
        assert np.all(np.isfinite(out)), (name, v, out)
    else:
        with pytest.raises(ValueError, match=param):
            f(v)


@pytest.mark.parametrize("row", ENTRY_POINTS, ids=[r[0] for r in ENTRY_POINTS])
@pytest.mark.parametrize("value", CLASSES, ids=[repr(v) for v in CLASSES])
def test_every_class_of_bad_value(row, value):
    _check(row, value)


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(ENTRY_POINTS), VALUES)
def test_any_value_is_an_error_naming_the_parameter_or_a_finite_result(row, value):
    _check(row, value)


def test_a_traced_call_is_not_checked_but_its_inputs_were():
    """Inside jit the values are not known: the check passes the tracer through (the engine validated its inputs
    before tracing), and the numbers are the untraced call's."""
    d = np.array([5.0, 30.0, 300.0])
    np.testing.assert_array_equal(jax.jit(propagation.los_probability)(d), propagation.los_probability(d))


def test_dpe_fix_refuses_nan_samples_and_empty_pilots():
    """The public fix (``dpe.fix``) on a user's signals: a NaN sample or a link whose pilots are all zero is a
    ValueError, not a NaN fix."""
    from dpe5g.phy import nr
    from dpe5g.receivers import dpe

    prs = np.asarray(nr.prs_matrix(range(3)))
    y = np.array(prs)
    bs = np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0], [0.0, 100.0, 10.0]])
    centre = np.array([50.0, 50.0, 2.0, 0.0])
    bad = y.copy()
    bad[1, 5] = np.nan
    with pytest.raises(ValueError, match="y and prs must be finite"):
        dpe.fix(bad, prs, bs, centre)
    empty = prs.copy()
    empty[2] = 0
    with pytest.raises(ValueError, match="prs must not be all zero"):
        dpe.fix(y, empty, bs, centre)
    two = (np.stack([y, y]), np.stack([prs, prs]))  # two trials
    with pytest.raises(ValueError, match=r"center_m must be \(2, 4\) and bs_xyz \(2, 3, 3\)"):
        dpe.fix(*two, np.stack([bs, bs]), np.stack([centre] * 3))
    with pytest.raises(ValueError, match=r"center_m must be \(2, 4\)"):
        dpe.fix(*two, bs, np.stack([centre] * 2))


@pytest.mark.parametrize("bad", ["../../../../somewhere/x", "a/b", "..", "", ".hidden", "x" * 101, 3, None])
def test_a_stored_thing_is_named_never_pathed(bad, tmp_path):
    """An experiment's or a traced city's name becomes a file name in the results store: a path, or what is not a
    name, is a ValueError naming the parameter, before any file is read or written."""
    from dpe5g.city import dataset

    with pytest.raises(ValueError, match="name must be a name of 1-100 letters"):
        experiment.Experiment.build(name=bad, n_trials=2, snrs_db=(20.0,), m_values=(4,))
    with pytest.raises(ValueError, match="name must be a name of 1-100 letters"):
        dataset.load_city(bad, root=tmp_path)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("bad", ["False", "True", 1, 0, None, 1.0])
def test_a_switch_is_true_or_false(bad):
    """A boolean setting takes True or False (or a NumPy bool): "False" would switch a receiver on, and 1 beside True
    would give two keys for one experiment."""
    with pytest.raises(ValueError, match="dpe_nlos must be True or False"):
        experiment.Experiment.build(dpe_nlos=bad, n_trials=2, snrs_db=(20.0,), m_values=(4,))
    with pytest.raises(ValueError, match="co_channel must be True or False"):
        experiment.Experiment.build(co_channel=bad, n_trials=2, snrs_db=(20.0,), m_values=(4,))
    assert (experiment.Experiment.build(dpe_nlos=np.bool_(False), n_trials=2).key()
            == experiment.Experiment.build(dpe_nlos=False, n_trials=2).key())
