import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dpe5g.phy import nr, signal
from dpe5g.receivers import cost
from dpe5g.simulation import engine, experiment
from dpe5g.phy.nr import Numerology

SMALL = Numerology(scs_hz=30e3, n_fft=64, n_rb=5)


@given(st.integers(0, 2**32 - 1), st.integers(1, 3), st.integers(1, 5))
def test_frequency_domain_equals_time_domain(seed, m, taps):
    rng = np.random.default_rng(seed)
    prs = nr.prs_matrix(rng.integers(0, 4096, size=m), SMALL)
    gains = rng.normal(size=(m, taps)) + 1j * rng.normal(size=(m, taps))
    tap_delays = rng.uniform(0, 12, size=(m, taps)) * SMALL.sample_period_s
    toa = rng.uniform(0, 30, size=m) * SMALL.sample_period_s
    bias = rng.uniform(-5, 5) * 1e-9
    fast = np.asarray(signal.received_noiseless(prs, gains, tap_delays, toa, bias, SMALL))
    direct = signal.received_noiseless_direct(prs, gains, tap_delays, toa, bias, SMALL)
    assert np.max(np.abs(fast - direct)) <= 1e-11 * np.max(np.abs(direct))


def test_integer_delay_is_circular_shift():
    prs = nr.prs_matrix([1, 2])
    ts = nr.PAPER.sample_period_s
    ones, zeros = np.ones((2, 1)), np.zeros((2, 1))
    y0 = np.asarray(signal.received_noiseless(prs, ones, zeros, np.zeros(2)))
    y3 = np.asarray(signal.received_noiseless(prs, ones, zeros, np.full(2, 3 * ts)))
    assert np.allclose(y3, np.roll(y0, 3, axis=1), atol=1e-12)
    # clock bias is the same as adding to every ToA
    yb = np.asarray(signal.received_noiseless(prs, ones, zeros, np.full(2, ts), clock_bias_s=2 * ts))
    assert np.allclose(yb, y3, atol=1e-12)


def test_noise_variance_matches_snr():
    prs = nr.prs_matrix([3])
    y = signal.received_samples(jax.random.PRNGKey(0), prs, np.zeros((1, 1)), np.zeros((1, 1)), np.zeros(1), 10.0)
    var = float(np.mean(np.abs(np.asarray(y)) ** 2))
    # 4096 samples: relative standard error of the variance estimate is 1/64
    assert var == pytest.approx(0.1, rel=4 / 64)


def test_noise_reproducible_per_key():
    prs = nr.prs_matrix([3, 4])
    args = (prs, np.ones((2, 1)), np.zeros((2, 1)), np.zeros(2), np.array([5.0, 20.0]))
    a = signal.received_samples(jax.random.PRNGKey(7), *args)
    b = signal.received_samples(jax.random.PRNGKey(7), *args)
    c = signal.received_samples(jax.random.PRNGKey(8), *args)
    assert np.array_equal(np.asarray(a), np.asarray(b))
    assert not np.array_equal(np.asarray(a), np.asarray(c))


@pytest.mark.parametrize("snr, match", [(float("nan"), "snr_db must be finite"), (300.0, "snr_db must be in")])
def test_bad_snr(snr, match):
    prs = nr.prs_matrix([3])
    with pytest.raises(ValueError, match=match):
        signal.received_samples(jax.random.PRNGKey(0), prs, np.ones((1, 1)), np.zeros((1, 1)), np.zeros(1), snr)


def test_bad_clock_bias():
    prs = nr.prs_matrix([3])
    with pytest.raises(ValueError, match="clock_bias_s"):
        signal.received_samples(jax.random.PRNGKey(0), prs, np.ones((1, 1)), np.zeros((1, 1)), np.zeros(1), 10.0,
                                clock_bias_s=float("nan"))


def test_computing_refuses_without_float64():
    """float64 is guaranteed where dpe5g computes: with x64 turned off after import, the entry points refuse."""
    import jax

    from dpe5g.phy import signal
    from dpe5g.receivers import correlogram, otdoa

    prs = np.ones((2, 64), complex)
    calls = [lambda: signal.ofdm_symbol(prs), lambda: signal.demodulate(prs),
             lambda: correlogram.ls_spectrum(prs, prs), lambda: cost.ml_cost(prs, prs, np.zeros(2), 4, 30e3),
             lambda: otdoa.toa(prs, prs), lambda: engine.run(experiment.Experiment.build(n_trials=1), progress=False)]
    jax.config.update("jax_enable_x64", False)
    try:
        for call in calls:
            with pytest.raises(RuntimeError, match="float64"):
                call()
    finally:
        jax.config.update("jax_enable_x64", True)
    assert np.asarray(signal.ofdm_symbol(prs)).dtype == np.complex128


def test_ofdm_symbol_is_eq3_by_hand():
    """Eq. (3) at t = nT_s after CP removal, x[n] = (1/√N) Σ_k d_k e^{j2πkn/N}, as a double loop on a small N."""
    num = Numerology(n_fft=64, n_rb=4)
    d = nr.prs_matrix([7], num)[0]
    by_hand = np.array([sum(d[k] * np.exp(2j * np.pi * k * n / 64) for k in range(64)) for n in range(64)]) / 8.0
    assert np.max(np.abs(np.asarray(signal.ofdm_symbol(d)) - by_hand)) < 1e-13
