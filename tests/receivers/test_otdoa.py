import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from dpe5g.phy import deployment, nr, signal
from dpe5g.receivers import otdoa
from dpe5g.phy.nr import C, PAPER


def _brute_force(bs, t, ue_z, centre, half=300.0):
    """Least squares of the range-difference residuals by nested grid search (no solver), to 1 mm."""
    best = np.asarray(centre, dtype=float)
    step = 2.0
    while step >= 0.001:
        ax = np.arange(-half, half + step / 2, step)
        gx, gy = np.meshgrid(best[0] + ax, best[1] + ax, indexing="ij")
        p = np.stack([gx, gy, np.full_like(gx, ue_z)], axis=-1)
        d = np.linalg.norm(p[..., None, :] - bs, axis=-1)
        r = (d[..., 1:] - d[..., :1]) - C * (t[1:] - t[0])
        ssr = np.sum(r**2, axis=-1)
        i = np.unravel_index(np.argmin(ssr), ssr.shape)
        best = np.array([gx[i], gy[i]])
        half, step = 5 * step, step / 5
    return best


def test_cvxpy_equals_brute_force_least_squares_noise_free():
    dep = deployment.tst()
    rng = np.random.default_rng(4)
    solver = otdoa.Solver(4)
    assert solver.problem.is_dpp()
    for _ in range(5):
        ue = np.array([*rng.uniform(50, 420, 2), 2.0])
        bs = dep.bs_xyz[dep.nearest(ue[:2], 4)]
        t = np.linalg.norm(ue - bs, axis=1) / C + rng.normal() * 5e-9  # a common clock bias cancels in TDoA
        fix = solver.solve(bs, t, 2.0, polish=False)
        brute = _brute_force(bs, t, 2.0, np.mean(bs[:, :2], axis=0))
        assert fix.ok and abs(fix.gap_m) < 0.01
        assert np.linalg.norm(fix.xyz[:2] - brute) <= 0.01
        assert np.linalg.norm(fix.xyz - ue) <= 0.01


@given(st.integers(0, 2**32 - 1), st.integers(4, 8))
def test_noise_free_fix_is_exact(seed, m):
    rng = np.random.default_rng(seed)
    bs = np.column_stack([rng.uniform(-300, 300, (m, 2)), rng.uniform(5, 40, m)])
    d = bs[1:, :2] - bs[0, :2]
    s = np.linalg.svd(d, compute_uv=False)
    assume(s[-1] > 0.2 * s[0])  # well-spread geometry
    ue = np.array([*rng.uniform(-100, 100, 2), 1.5])
    t = np.linalg.norm(ue - bs, axis=1) / C
    fix = otdoa.solve(bs, t, 1.5)
    assert fix.ok and np.linalg.norm(fix.xyz - ue) <= 0.01


def test_bad_inputs():
    bs = np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0], [0.0, 100.0, 10.0], [80.0, 90.0, 10.0]])
    t = np.full(4, 1e-7)
    with pytest.raises(ValueError, match="at least 3 base stations"):
        otdoa.solve(bs[:2], t[:2], 2.0)
    with pytest.raises(ValueError, match="collinear"):
        otdoa.solve(np.array([[0.0, 0, 10], [50, 50, 10], [100, 100, 10], [150, 150, 10]]), t, 2.0)
    with pytest.raises(ValueError, match="toa_s must be finite"):
        otdoa.solve(bs, [1e-7, np.nan, 1e-7, 1e-7], 2.0)
    with pytest.raises(ValueError, match="method must be one of"):
        otdoa.toa(np.zeros((2, 4096), complex), nr.prs_matrix([1, 2]), method="strongest")


def test_toa_peak_and_first_path():
    prs = nr.prs_matrix([3])
    ts = PAPER.sample_period_s
    tau = 0.4123e-6
    # a weak first path and a stronger one 3 samples later
    y = signal.received_noiseless(prs, np.array([[0.6, 1.0]]), np.array([[0.0, 3 * ts]]), np.array([tau]))
    peak = float(otdoa.toa(y, prs, "peak")[0])
    first = float(otdoa.toa(y, prs, "first_path", threshold_db=-10.0)[0])
    assert abs(peak - (tau + 3 * ts)) * C < 0.3  # the strongest path, 3 samples (7.3 m) late
    assert abs(first - tau) * C < 0.5  # the first path (its estimate pulled 0.3 m by the second path's tail)
    y1 = signal.received_noiseless(prs, np.array([[1.0]]), np.array([[0.0]]), np.array([tau]))
    assert abs(float(otdoa.toa(y1, prs)[0]) - tau) * C < 0.05  # single path: parabola on the T_s/8 grid
    assert float(otdoa.toa(y, prs)[0]) == first  # the default is the first-path detector, not the paper's peak


def test_runaway_polish_is_flagged_not_silent():
    bs = np.array([[0.0, 0.0, 10.0], [100.0, 0.0, 10.0], [0.0, 100.0, 10.0], [100.0, 100.0, 10.0]])
    t = np.array([0.0, 400.0, -400.0, 390.0]) / C  # range differences no position can produce
    fix = otdoa.solve(bs, t, 2.0)
    assert np.all(np.isfinite(fix.xyz))
    if not fix.ok:
        assert fix.reason
    assert fix.residual_m > 1.0


def test_a_fix_does_not_depend_on_the_solves_before_it():
    # a Solver is reused across trials: its fix of one problem must not carry state (a warm start) from the last
    rng = np.random.default_rng(5)
    bs = np.column_stack([rng.uniform(-300, 300, (5, 2)), np.full(5, 20.0)])
    ue = np.array([12.0, -7.0, 1.5])
    probs = [np.linalg.norm(bs - ue, axis=1) / C + rng.normal(0, 5e-9, 5) for _ in range(3)]
    used = otdoa.Solver(5)
    for t in probs[:2]:
        used.solve(bs, t, 1.5, polish=False)
    a = used.solve(bs, probs[2], 1.5, polish=False)
    b = otdoa.Solver(5).solve(bs, probs[2], 1.5, polish=False)
    np.testing.assert_array_equal(a.xyz, b.xyz)


@given(st.integers(0, 2**32 - 1), st.integers(3, 12), st.booleans())
def test_solver_data_and_fix_equal_cvxpys_own_solve(seed, m, zeros):
    """``Solver`` applies the affine parameter → data map it read from cvxpy; the data must be cvxpy's to the bit
    (values and CSC structure, with parameters that are exactly zero too), and the solution the one
    ``Problem.solve`` finds."""
    import cvxpy as cp

    rng = np.random.default_rng(seed)
    solver = otdoa.Solver(m)
    A, beta, ref, dz = rng.normal(size=(m - 1, 3)), rng.normal(size=m - 1), rng.normal(size=2), float(rng.normal())
    if zeros:
        A[rng.integers(m - 1), rng.integers(3)], beta[0], dz = 0.0, 0.0, 0.0
    mine = solver.data(A, beta, ref, dz)
    solver.A.value, solver.beta.value, solver.ref.value, solver.dz.value = A, beta, ref, dz
    theirs = solver.problem.get_problem_data(cp.CLARABEL)[0]
    for key in ("c", "b"):
        np.testing.assert_array_equal(mine[key], theirs[key])
    for attr in ("data", "indices", "indptr", "shape"):
        np.testing.assert_array_equal(getattr(mine["A"], attr), getattr(theirs["A"], attr))
    # the fix: ``solve`` (without polish) against cvxpy's own ``Problem.solve`` on the same system
    bs = np.column_stack([rng.uniform(-300, 300, (m, 2)), rng.uniform(5, 40, m)])
    t = np.linalg.norm(bs - np.array([10.0, -20.0, 1.5]), axis=1) / C + rng.normal(0, 5e-9, m)
    fix = solver.solve(bs, t, 1.5, polish=False)
    solver.set_parameters(bs, t, 1.5)
    solver.problem.solve(solver=cp.CLARABEL, warm_start=False)
    np.testing.assert_array_equal(fix.xyz[:2], solver.theta.value[:2] * 1000.0)
