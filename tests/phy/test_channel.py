import jax
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dpe5g.phy import channel
from dpe5g.phy.nr import PAPER

NAMES = list("ABCDE")


def test_table_sizes_and_k_factors():
    assert [len(channel.TABLES[n].delays_norm) for n in NAMES] == [23, 23, 24, 14, 15]
    for n in NAMES:
        t = channel.TABLES[n]
        assert len(t.delays_norm) == len(t.powers_db)
    assert channel.TABLES["D"].k_factor_db == pytest.approx(13.3)
    assert channel.TABLES["E"].k_factor_db == pytest.approx(22.0)
    assert channel.TABLES["C"].k_factor_db is None
    # spot values, TR 38.901 Tables 7.7.2-1..5
    assert channel.TABLES["A"].delays_norm[-1] == 9.6586 and channel.TABLES["A"].powers_db[-1] == -29.7
    assert channel.TABLES["C"].delays_norm[5] == 0.6366 and channel.TABLES["C"].powers_db[5] == 0.0
    assert channel.TABLES["E"].delays_norm[-1] == 20.6519


@given(st.sampled_from(NAMES), st.floats(1e-9, 1e-6))
def test_scaled_profile_gives_back_desired_spread(name, ds):
    prof = channel.tdl_profile(name, ds)
    assert prof.powers.sum() == pytest.approx(1.0, abs=1e-12)
    # tables are rounded to 4 digits / 0.1 dB: their normalized spread is 1 within 1 % (TDL-D: 0.9937)
    assert channel.rms_delay_spread(prof.delays_s, prof.powers) == pytest.approx(ds, rel=0.01)


@given(st.sampled_from("DE"), st.floats(0.0, 30.0), st.floats(1e-9, 1e-6))
def test_k_factor_override(name, k, ds):
    prof = channel.tdl_profile(name, ds, k_factor_db=k)
    assert prof.powers_db[0] - prof.powers_db[1] == pytest.approx(k, abs=1e-9)
    assert prof.powers.sum() == pytest.approx(1.0, abs=1e-12)
    assert channel.rms_delay_spread(prof.delays_s, prof.powers) == pytest.approx(ds, rel=1e-9)


def test_rms_delay_spread_two_taps():
    # two equal taps 2 s apart: spread 1 s
    assert channel.rms_delay_spread([0.0, 2.0], [1.0, 1.0]) == pytest.approx(1.0)


def test_draw_gains_statistics():
    prof = channel.tdl_profile("C", 65e-9)
    g = jax.vmap(lambda k: channel.draw_gains(prof, k))(jax.random.split(jax.random.PRNGKey(0), 20000))
    p = np.mean(np.abs(np.asarray(g)) ** 2, axis=0)
    assert np.max(np.abs(p / prof.powers - 1)) < 5 / np.sqrt(20000)
    prof_d = channel.tdl_profile("D", 65e-9)
    gd = np.asarray(channel.draw_gains(prof_d, jax.random.PRNGKey(1)))
    assert abs(gd[0]) == pytest.approx(np.sqrt(prof_d.powers[0]), rel=1e-12)


def test_draw_gains_deterministic():
    prof = channel.tdl_profile("A", 65e-9)
    a = channel.draw_gains(prof, jax.random.PRNGKey(3))
    b = channel.draw_gains(prof, jax.random.PRNGKey(3))
    assert np.array_equal(np.asarray(a), np.asarray(b))


def test_sampled_cir_integer_taps():
    ts = PAPER.sample_period_s
    h = np.asarray(channel.sampled_cir(np.array([0.7079, 1.0, 0.8913]), np.array([0.0, 1.0, 2.0]) * ts))
    assert np.allclose(h[:3], [0.7079, 1.0, 0.8913], atol=1e-12)
    assert np.max(np.abs(h[3:])) < 1e-12


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        (("F", 65e-9), {}, "profile must be one of A, B, C, D, E"),
        (("C", 65), {}, "nanoseconds"),
        (("C", 0.0), {}, "delay_spread_s"),
        (("C", -1e-9), {}, "delay_spread_s"),
        (("C", float("nan")), {}, "delay_spread_s must be finite"),
        (("C", 65e-9), {"k_factor_db": 10.0}, "k_factor_db applies to the LoS profiles"),
        (("D", 65e-9), {"k_factor_db": float("nan")}, "k_factor_db"),
    ],
)
def test_bad_input(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        channel.tdl_profile(*args, **kwargs)


def test_span_definition_of_the_delay_spread():
    """"span" (the paper's text): last tap delay_spread_s after the first, powers unchanged; "rms" (TR 38.901): RMS
    spread delay_spread_s."""
    for name in ("A", "B", "C", "D", "E"):
        rms = channel.tdl_profile(name, 65e-9)
        span = channel.tdl_profile(name, 65e-9, definition="span")
        assert span.delays_s.max() - span.delays_s.min() == pytest.approx(65e-9, rel=1e-12)
        np.testing.assert_allclose(span.powers, rms.powers)
        np.testing.assert_allclose(span.delays_s / span.delays_s.max(), rms.delays_s / rms.delays_s.max())
    assert channel.rms_delay_spread(channel.tdl_profile("C", 65e-9).delays_s,
                                    channel.tdl_profile("C", 65e-9).powers) == pytest.approx(65e-9, rel=1e-4)
    with pytest.raises(ValueError, match="definition"):
        channel.tdl_profile("C", 65e-9, definition="mean")
