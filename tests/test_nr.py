import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dpe5g import nr


def gold_bit_by_bit(c_init, length, nc=1600):
    """TS 38.211 §5.2.1 transcribed one bit at a time."""
    x1 = [1] + [0] * 30
    x2 = [(c_init >> i) & 1 for i in range(31)]
    for n in range(length + nc):
        x1.append((x1[n + 3] + x1[n]) % 2)
        x2.append((x2[n + 3] + x2[n + 2] + x2[n + 1] + x2[n]) % 2)
    return np.array([(x1[n + nc] + x2[n + nc]) % 2 for n in range(length)], dtype=np.uint8)


def test_paper_numerology():
    n = nr.PAPER
    assert n.sample_rate_hz == pytest.approx(122.88e6, abs=1e-3)
    assert n.sample_spacing_m == pytest.approx(2.4397, abs=1e-4)
    assert n.n_active == 3276
    assert n.cp_samples == 288
    assert n.cp_s == pytest.approx(2.34375e-6)
    assert n.mu == 1 and n.slots_per_frame == 20


@given(st.integers(0, 2**31 - 1), st.integers(0, 300))
def test_gold_sequence_matches_bitwise(c_init, length):
    assert np.array_equal(nr.gold_sequence(c_init, length), gold_bit_by_bit(c_init, length))


def test_prs_c_init_formula():
    # n_ID = 1500: floor(1500/1024) = 1, 1500 mod 1024 = 476; slot 3, symbol 5.
    expected = (2**22 * 1 + 2**10 * (14 * 3 + 5 + 1) * (2 * 476 + 1) + 476) % 2**31
    assert nr.prs_c_init(1500, 3, 5) == expected


def test_prs_full_band_unit_modulus_and_distinct():
    a, b = nr.prs_symbols(1), nr.prs_symbols(2)
    assert a.shape == (4096,)
    assert np.allclose(np.abs(a), 1.0)
    assert np.all(np.isin(np.round(a.real * np.sqrt(2)), [-1, 1]))
    assert abs(np.vdot(a, b)) / 4096 < 0.1  # different IDs are nearly orthogonal


@pytest.mark.parametrize("comb", [2, 4, 6, 12])
def test_prs_comb_pattern(comb):
    d = nr.prs_symbols(9, pattern="comb", comb=comb, comb_offset=1)
    nz = np.flatnonzero(d)
    assert nz.size == 3276 // comb
    assert set(nz) <= set(nr.active_bins().tolist())
    assert np.allclose(np.abs(d[nz]), 1.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(prs_id=4096), "prs_id"),
        (dict(prs_id=1, pattern="sparse"), "pattern"),
        (dict(prs_id=1, pattern="comb", comb=3), "comb"),
        (dict(prs_id=1, pattern="comb", comb=4, comb_offset=4), "comb_offset"),
    ],
)
def test_prs_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        nr.prs_symbols(**kwargs)


def test_numerology_bad_input():
    with pytest.raises(ValueError, match="scs_hz"):
        nr.Numerology(scs_hz=25e3)
    with pytest.raises(ValueError, match="n_rb"):
        nr.Numerology(n_fft=64, n_rb=273)
