import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dpe5g.phy import nr, signal
from dpe5g.receivers import correlogram, cost, dpe, grid_search, search_config, spline_boxes
from dpe5g.phy.nr import C, PAPER, Numerology


def random_case(seed, n_fft, m, n_tau):
    rng = np.random.default_rng(seed)
    num = PAPER if n_fft == 4096 else Numerology(n_fft=n_fft, n_rb=min(5, n_fft // 12))
    prs = nr.prs_matrix(rng.integers(0, 4096, size=m), num)
    y = rng.normal(size=(m, n_fft)) + 1j * rng.normal(size=(m, n_fft))
    tau = rng.uniform(-1e-6, 3e-6, size=(n_tau, m))
    return y, prs, tau, num


@settings(max_examples=10)  # each new (n_fft, m, L) compiles; the full-size case is the test below
@given(st.integers(0, 2**32 - 1), st.sampled_from([64, 256]), st.integers(1, 4), st.integers(1, 12))
def test_fast_cost_equals_literal(seed, n_fft, m, n_taps):
    y, prs, tau, num = random_case(seed, n_fft, m, 3)
    lit = cost.ml_cost_literal(y, prs, tau, n_taps, num.scs_hz)
    fast = np.asarray(cost.ml_cost(y, prs, tau, n_taps, num.scs_hz))
    assert np.all(np.abs(fast - lit) <= 1e-9 * np.abs(lit))


def test_fast_cost_equals_literal_full_size():
    y, prs, tau, num = random_case(1, 4096, 2, 2)
    lit = cost.ml_cost_literal(y, prs, tau, 8, num.scs_hz)
    fast = np.asarray(cost.ml_cost(y, prs, tau, 8, num.scs_hz))
    assert np.all(np.abs(fast - lit) <= 1e-9 * np.abs(lit))


def test_correlogram_exact_on_its_grid():
    y, prs, _, num = random_case(2, 256, 3, 1)
    u = 8
    corr = correlogram.correlogram(y, prs, 6, u)
    ts = num.sample_period_s
    j = np.array([0, 1, 7, 8, 100, 256 * u - 1])
    tau = np.repeat((j * ts / u)[:, None], 3, axis=1)
    ref = np.asarray(cost.ml_cost(y, prs, tau, 6, num.scs_hz))
    got = np.asarray(cost.correlogram_lookup(corr, tau, ts, u))
    assert np.allclose(got, ref, rtol=1e-10)


def test_correlogram_cubic_interpolation_between_grid_points():
    y, prs, _, num = random_case(5, 256, 3, 1)
    ts, u = num.sample_period_s, 8
    corr = correlogram.correlogram(y, prs, 6, u)
    tau = np.random.default_rng(0).uniform(0, 256 * ts, size=(200, 3))
    ref = np.asarray(cost.ml_cost(y, prs, tau, 6, num.scs_hz))
    got = np.asarray(cost.correlogram_lookup(corr, tau, ts, u))
    err = np.abs(got - ref)
    assert err.max() <= 2e-3 * ref.max()
    assert err.max() > 0  # between grid points it is an interpolation, not the exact cost


def test_cost_of_matched_signal_is_channel_energy():
    # noise-free, channel taps on the sample grid inside the window: cost at the true ToA = N Σ|h|² per BS
    prs = nr.prs_matrix([4, 5])
    h = np.array([[0.7079, 1.0, 0.8913]] * 2)
    ts = PAPER.sample_period_s
    tau = np.array([1.3e-6, 0.77e-6])
    y = signal.received_noiseless(prs, h, np.array([[0, 1, 2]] * 2) * ts, tau)
    value = float(cost.ml_cost(y, prs, tau[None], 3, PAPER.scs_hz)[0])
    assert value == pytest.approx(4096 * 2 * np.sum(h[0] ** 2), rel=1e-10)


def _geometry(m=8, radius=150.0):
    ang = np.arange(m) * 2 * np.pi / m + 0.3
    return np.stack([radius * np.cos(ang), radius * np.sin(ang), np.full(m, 10.0)], axis=-1)


@pytest.mark.parametrize("bias", [0.0, 4e-9])
def test_fix_noise_free_three_tap_channel(bias):
    bs = _geometry()
    ue = np.array([3.3, -2.1, 2.0])
    prs = nr.prs_matrix(range(8))
    h = np.tile([0.7079, 1.0, 0.8913], (8, 1))
    ts = PAPER.sample_period_s
    y = signal.received_noiseless(prs, h, np.tile([0.0, ts, 2 * ts], (8, 1)), cost.toa(ue, bs, 0.0), bias)
    est = dpe.fix(y, prs, bs, np.array([0.0, 0.0, 2.0, 0.0]), search_config.SearchConfig(n_taps=3))
    assert np.linalg.norm(est.xyz[:2] - ue[:2]) < 0.1
    assert abs(est.clock_bias_s - bias) * C < 0.1


def _three_tap(bs, ue, bias, prs):
    h = np.tile([0.7079, 1.0, 0.8913], (len(bs), 1))
    ts = PAPER.sample_period_s
    return signal.received_noiseless(prs, h, np.tile([0.0, ts, 2 * ts], (len(bs), 1)), cost.toa(ue, bs, 0.0), bias)


def test_polish_reaches_the_exact_maximum():
    bs, prs = _geometry(), nr.prs_matrix(range(8))
    ue = np.array([3.33, -2.17, 2.0])
    y = _three_tap(bs, ue, 2e-9, prs)
    center = np.array([0.0, 0.0, 2.0, 0.0])
    grid = dpe.fix(y, prs, bs, center, search_config.SearchConfig(n_taps=3))
    pol = dpe.fix(y, prs, bs, center, search_config.SearchConfig(n_taps=3, polish=True))
    assert np.linalg.norm(pol.xyz - ue) < 0.01 < np.linalg.norm(grid.xyz - ue)
    assert abs(pol.clock_bias_s - 2e-9) * C < 0.01
    assert pol.cost >= grid.cost


def test_fix_3d_search():
    # BSs at different heights make z observable; the search starts 3 m below the true UE height
    bs = _geometry(radius=60.0)
    bs[:, 2] = [5.0, 40.0, 10.0, 25.0, 5.0, 40.0, 10.0, 25.0]
    prs = nr.prs_matrix(range(8))
    ue = np.array([1.4, 2.6, 4.5])
    y = _three_tap(bs, ue, 2e-9, prs)
    cfg = search_config.SearchConfig(n_taps=3, z_half_width_m=5.0, polish=True)
    est = dpe.fix(y, prs, bs, np.array([0.0, 0.0, 1.5, 0.0]), cfg)
    assert np.linalg.norm(est.xyz - ue) < 0.05
    flat = dpe.fix(y, prs, bs, np.array([0.0, 0.0, 1.5, 0.0]), search_config.SearchConfig(n_taps=3))
    assert flat.xyz[2] == 1.5  # without the z search the height stays at the centre's


def test_fix_batched_equals_single():
    bs = _geometry()
    prs = nr.prs_matrix(range(8))
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    ues = np.array([[1.0, 2.0, 2.0], [-4.0, 0.5, 2.0]])
    ys = np.stack([
        signal.received_samples(k, prs, np.ones((8, 1)), np.zeros((8, 1)), cost.toa(u, bs, 0.0), 10.0)
        for k, u in zip(keys, ues)
    ])
    center = np.array([0.0, 0.0, 2.0, 0.0])
    grid = search_config.SearchConfig()  # (the paper's grid: batching is the same for either search, and it compiles fast)
    batch = dpe.fix(ys, np.stack([prs] * 2), np.stack([bs] * 2), np.stack([center] * 2), grid)
    chunked = dpe.fix(ys, np.stack([prs] * 2), np.stack([bs] * 2), np.stack([center] * 2), grid, batch_size=1)
    for i in range(2):
        one = dpe.fix(ys[i], prs, bs, center, grid)
        assert np.allclose(batch.xyz[i], one.xyz, atol=1e-9)
        assert np.allclose(chunked.xyz[i], one.xyz, atol=1e-9)


def test_the_default_fix_is_the_honest_certified_receiver():
    """With no search given, ``fix`` runs the book's honest receiver: the certified branch and bound in a window
    that covers the clock prior (± 3 σ of the paper's 5 ns), the search Fig. 9's honest experiment runs."""
    from dpe5g.studies import paper

    assert dpe.honest_search() == paper.fig9_honest().receiver_search()
    assert dpe.honest_search().method == "bnb" and dpe.honest_search().bias_half_width_m >= 3 * 5e-9 * C - 1e-9
    # 4 BSs, pure delay, 10 dB per sample, a 3 ns clock bias, the window centred 5.6 m off the UE.  (With L = 12
    # taps a pure delay leaves c δt free over a plateau of a few samples: the bias is not what is checked.)
    bs = _geometry(4)
    prs = nr.prs_matrix(range(4))
    ue, bias = np.array([3.0, -2.0, 2.0]), 3e-9
    y = signal.received_samples(jax.random.PRNGKey(7), prs, np.ones((4, 1)), np.zeros((4, 1)),
                                cost.toa(ue, bs, bias), 10.0)
    est = dpe.fix(y, prs, bs, np.array([6.0, 2.0, 2.0, 0.0]))
    assert bool(est.certified) and not bool(est.edge) and float(est.gap) <= dpe.honest_search().gap_tol
    assert np.linalg.norm(est.xyz[:2] - ue[:2]) < 0.1


def test_bad_inputs():
    y, prs, tau, num = random_case(3, 64, 2, 1)
    with pytest.raises(ValueError, match="n_taps"):
        cost.ml_cost(y, prs, tau, 0, num.scs_hz)
    with pytest.raises(ValueError, match="tau must have shape"):
        cost.ml_cost(y, prs, tau[:, :1], 4, num.scs_hz)
    with pytest.raises(ValueError, match="y and prs"):
        cost.ml_cost(y, prs[:1], tau, 4, num.scs_hz)
    with pytest.raises(ValueError, match="z_half_width_m"):
        search_config.SearchConfig(z_half_width_m=-1.0)
    with pytest.raises(ValueError, match="final_step_m"):
        search_config.SearchConfig(final_step_m=5.0)
    with pytest.raises(ValueError, match="finite"):
        dpe.fix(np.ones((3, 4096), complex), nr.prs_matrix([1, 2, 3]), _geometry(3), [np.nan, 0, 2, 0])
    with pytest.raises(ValueError, match="y and prs must be"):  # one link's samples, no link axis
        dpe.fix(np.ones(4096, complex), nr.prs_matrix([1])[0], _geometry(1)[0], [0, 0, 2, 0])
    with pytest.raises(ValueError, match="at least 3 links .* got M = 2"):  # x, y and the clock bias: 3 unknowns
        dpe.fix(np.ones((2, 4096), complex), nr.prs_matrix([1, 2]), _geometry(2), [0, 0, 2, 0])
    y = np.ones((2, 3, 4096), complex)
    y[1] = 0  # the second trial received nothing
    with pytest.raises(ValueError, match="at least 3 links of each trial .* a trial has 0"):
        dpe.fix(y, np.broadcast_to(nr.prs_matrix([1, 2, 3]), y.shape), np.broadcast_to(_geometry(3), (2, 3, 3)),
                np.zeros((2, 4)))
    y[1, :2] = 1.0  # two links carry a signal: still one unknown too many
    with pytest.raises(ValueError, match="at least 3 links of each trial .* a trial has 2"):
        dpe.fix(y, np.broadcast_to(nr.prs_matrix([1, 2, 3]), y.shape), np.broadcast_to(_geometry(3), (2, 3, 3)),
                np.zeros((2, 4)))


def test_ls_estimate_recovers_the_channel():
    """Eq. (8): with unit-modulus pilots the LS estimate D^H F^H y is the channel's frequency response, whose
    inverse DFT gives back the taps (noise-free, taps on the sample grid, ToA 0)."""
    prs = nr.prs_matrix([4])
    h = np.array([[0.7079, 1.0, 0.8913]])
    y = signal.received_noiseless(prs, h, np.array([[0, 1, 2]]) * PAPER.sample_period_s, np.zeros(1))
    g = np.asarray(correlogram.ls_spectrum(signal.demodulate(y), prs))
    h_hat = np.fft.ifft(g, axis=-1)
    assert np.allclose(h_hat[0, :3], h[0], atol=1e-12) and np.max(np.abs(h_hat[0, 3:])) < 1e-12


@pytest.mark.parametrize("spacing", ["T_s", "band"])
def test_window_taps_on_the_band_spacing_keep_the_first_path(spacing):
    """Pilots on the carrier's contiguous band of K < N bins (the standard's PRS): a single path's LS pulse is wider
    than T_s, so eq. (10)'s window with taps T_s apart (not orthogonal over the band) is largest with the window
    spread over the pulse, before the path; with taps ``band_tap_spacing`` apart (orthogonal over the band) the
    window that starts at the path holds the maximum, as it does for the paper's full-band pilots."""
    import jax.numpy as jnp

    n, u, taps = PAPER.n_fft, 8, 12
    d = nr.prs_per_subcarrier(2, nr.PrsPattern(6), 3)
    tau0 = 100.3  # samples
    g = np.abs(d) ** 2 * np.exp(-2j * np.pi * np.arange(n) * tau0 / n)
    s = 1.0 if spacing == "T_s" else correlogram.band_tap_spacing(PAPER)
    assert correlogram.band_tap_spacing(PAPER) == pytest.approx(4096 / 3276)
    window = jnp.asarray(correlogram.window_spectrum(taps, n, None, s))
    coef = correlogram.spline_coefficients(jnp.asarray(g)[None], window, u)
    t = tau0 + np.arange(-20.0, 3.0, 1 / 64)
    values = np.asarray(spline_boxes.spline_values(coef, jnp.asarray(t * u)[:, None]))
    at_path = float(spline_boxes.spline_values(coef, jnp.asarray([[tau0 * u]]))[0])
    if spacing == "band":
        assert at_path >= values.max() * (1 - 5e-5)  # the spline's own error is ≤ 2e-5 of the peak (Chapter 3)
    else:
        assert at_path < 0.97 * values.max() and t[np.argmax(values)] < tau0 - 1


def test_cir_grid_is_the_phase_ramped_transforms():
    """``correlogram.cir_grid`` (one zero-padded transform of length U·N) equals U inverse FFTs of length N of the
    spectrum delayed by u T_s/U, entry n·U + u = ĥ((n + u/U) T_s)/√N; ``half_sample_cir`` is its U = 2."""
    g = np.random.default_rng(0).normal(size=(3, 64)) + 1j * np.random.default_rng(1).normal(size=(3, 64))
    k = np.arange(64)
    for u in (1, 2, 4, 8):
        ramped = np.stack([np.fft.ifft(g * np.exp(2j * np.pi * k * v / (u * 64)), axis=-1) for v in range(u)], -1)
        np.testing.assert_allclose(np.asarray(correlogram.cir_grid(jax.numpy.asarray(g), u)),
                                   ramped.reshape(3, 64 * u), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(np.asarray(correlogram.half_sample_cir(jax.numpy.asarray(g))),
                                  np.asarray(correlogram.cir_grid(jax.numpy.asarray(g), 2)))


@given(st.floats(-25.0, 25.0), st.floats(-25.0, 25.0), st.floats(-12.0, 12.0), st.integers(0, 3))
def test_grid_window_holds_every_lookup_of_the_search(dx, dy, db, which):
    """Every grid point the search's cubic reads, at any level (first level around the centre, finer levels around any
    point the previous level can pick), lies inside ``grid_window``'s W points; so the windowed search is the whole
    correlogram's (Chapter 3 checks one fix; this checks the bound, for several search configs)."""
    cfg = [search_config.SearchConfig(), search_config.SearchConfig(half_width_m=3.0, bias_half_width_m=0.0),
           search_config.SearchConfig(z_half_width_m=5.0, upsample=8), search_config.SearchConfig(coarse_step_m=2.0, final_step_m=0.05)][which]
    rng = np.random.default_rng(int(abs(dx * 1e3)) % 1000)
    bs = np.column_stack([rng.uniform(-300, 300, (12, 2)), rng.uniform(5, 40, 12)])
    center = np.array([dx, dy, 2.0, db])
    start = np.asarray(grid_search.grid_window(jax.numpy.asarray(bs), jax.numpy.asarray(center), cfg))
    width = grid_search.grid_window_cells(cfg)
    reach_xy, reach_z, reach_b = grid_search.grid_reach(cfg)
    # the candidates' extreme points: the corners and faces of the reach box, and a dense sample inside it
    ax = np.linspace(-1, 1, 9)
    off = np.stack(np.meshgrid(ax * reach_xy, ax * reach_xy, ax * reach_z, ax * reach_b, indexing="ij"), -1).reshape(-1, 4)
    q = center + off
    tau = np.linalg.norm(q[:, None, :3] - bs, axis=-1) / C + q[:, 3:4] / C
    pos = np.floor(tau / PAPER.sample_period_s * cfg.upsample)
    assert np.all(pos - 1 >= start) and np.all(pos + 2 <= start + width - 1), (pos.min(0) - start, pos.max(0) - start)
