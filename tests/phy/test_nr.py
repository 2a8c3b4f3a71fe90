import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dpe5g.phy import nr


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


VALID_PATTERNS = [(k, n) for k in nr.PRS_COMB_SIZES for n in nr.PRS_SYMBOL_COUNTS if n >= k and n % k == 0]


def test_valid_pattern_list_is_the_standards():
    # TS 38.211 §7.4.1.7.3 (Rel-16): {L_PRS, K_comb} in {2,2} {4,2} {6,2} {12,2} {4,4} {12,4} {6,6} {12,6} {12,12}
    assert sorted(VALID_PATTERNS) == sorted([(2, 2), (2, 4), (2, 6), (2, 12), (4, 4), (4, 12), (6, 6), (6, 12),
                                             (12, 12)])


@pytest.mark.parametrize("comb, n_symbols", VALID_PATTERNS)
def test_prs_resource_elements_follow_the_standard(comb, n_symbols):
    """RE positions against the formula of TS 38.211 §7.4.1.7.3 read as a membership test: subcarrier k of symbol
    l carries the PRS iff k ≡ k_offset + k'(l - l_start) (mod K_comb), over the 3276 active subcarriers."""
    table = {2: [0, 1] * 6, 4: [0, 2, 1, 3] * 3, 6: [0, 3, 1, 4, 2, 5] * 2, 12: [0, 6, 3, 9, 1, 7, 4, 10, 2, 8, 5, 11]}
    p = nr.PrsPattern(comb, n_symbols)
    for offset in range(comb):
        sc = p.subcarriers(offset)
        assert sc.shape == (n_symbols, 3276 // comb)
        for i in range(n_symbols):
            expected = [k for k in range(3276) if k % comb == (offset + table[comb][i]) % comb]
            assert sc[i].tolist() == expected
        np.testing.assert_array_equal(p.resource_elements(offset), nr.band_bins()[sc])
        # energy of the paper's full-band symbol, whatever the pattern and offset
        g = nr.prs_grid(5, p, offset)
        assert g.shape == (n_symbols, 4096)
        assert np.sum(np.abs(g) ** 2) == pytest.approx(4096)
        assert np.count_nonzero(g) == n_symbols * 3276 // comb
    # different offsets never share an RE
    used = np.stack([np.abs(nr.prs_grid(5, p, o)) > 0 for o in range(comb)])
    assert np.all(used.sum(axis=0) <= 1)


def test_fully_staggered_pattern_covers_each_active_subcarrier_once():
    p = nr.PrsPattern(6)
    assert p.n_symbols == 6
    d = nr.prs_per_subcarrier(17, p, 4)
    assert np.flatnonzero(d).tolist() == nr.band_bins().tolist()
    # one contiguous block of eq. (3)'s bins (bin k the tone at k Δf), centred: guard bands of equal width
    b = nr.band_bins()
    assert np.all(np.diff(b) == 1) and b[0] == 4096 - 1 - b[-1] == (4096 - 3276) // 2
    assert np.sum(np.abs(d) ** 2) == pytest.approx(4096)
    # each pilot is its symbol's sequence: r_l(m) of §7.4.1.7.2 at m = k // K_comb
    g = nr.prs_grid(17, p, 4)
    np.testing.assert_array_equal(d, g.sum(axis=0))


@pytest.mark.parametrize("kwargs, match", [
    (dict(comb_size=3), "comb_size must be one of"),
    (dict(comb_size=6, n_symbols=4), "n_symbols must be a multiple"),
    (dict(comb_size=2, n_symbols=3), "n_symbols must be one of"),
    (dict(comb_size=6, start_symbol=9), "start_symbol"),
])
def test_prs_pattern_bad_input(kwargs, match):
    with pytest.raises(ValueError, match=match):
        nr.PrsPattern(**kwargs)


def test_prs_pattern_bad_offset_and_id():
    p = nr.PrsPattern(4)
    with pytest.raises(ValueError, match="comb_offset"):
        p.subcarriers(4)
    with pytest.raises(ValueError, match="prs_id"):
        nr.prs_grid(4096, p, 0)
    with pytest.raises(ValueError, match="n_symbols must equal comb_size"):
        nr.prs_per_subcarrier(1, nr.PrsPattern(2, 4), 0)


def test_staggered_prs_has_the_delay_kernel_of_one_contiguous_band():
    """Eq. (3)'s convention (bin k the tone at k Δf): the pilots of a resource must occupy one contiguous band, so
    that the LS CIR estimate of a pure delay peaks there with sinc sidelobes (at most -13.26 dB), as the paper's
    full band does; a band split in two would put sidelobes of the split's beat inside the main lobe's neighbours."""
    num = nr.PAPER
    d = nr.prs_per_subcarrier(2, nr.PrsPattern(6), 3)
    k = np.arange(num.n_fft)
    tau = 37.3 * num.sample_period_s
    g = np.abs(d) ** 2 * np.exp(-2j * np.pi * k * num.scs_hz * tau)  # conj(d) · d e^{-j2πkΔfτ}
    t = tau + np.arange(-20, 20, 1 / 64) * num.sample_period_s
    e = np.abs(np.exp(2j * np.pi * num.scs_hz * np.outer(t, k)) @ g) ** 2
    assert abs(t[np.argmax(e)] - tau) < num.sample_period_s / 64
    main = np.abs(t - tau) < num.n_fft / num.n_active * num.sample_period_s  # the main lobe, ±N/n_active samples
    assert 10 * np.log10(e[~main].max() / e.max()) < -13.0
