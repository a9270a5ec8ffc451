"""The output-error fit's shortcuts against the long way: the compressed least-squares problem
(linear algebra identities), the coarse thrust grid (the full-rate simulation), and the
smoother and surge lag computed without scipy.signal (scipy.signal itself)."""

from __future__ import annotations

import numpy as np

from usvlog.identify.data import run_data
from usvlog.identify.output import Problem, compress_lsq, simulate_run
from usvlog.identify.smooth import savgol_filter
from usvlog.identify.surge import _lag
from usvlog.model.vessel import VesselParams
from usvlog.sim.simulate import SimSettings, simulate


def test_compressed_problem_keeps_normal_equations_and_cost():
    rng = np.random.default_rng(3)
    J = rng.normal(size=(5000, 7)) * np.array([1e3, 1.0, 1e-2, 5.0, 1.0, 1e2, 0.3])
    r = rng.normal(size=5000)
    for JJ in (J, np.column_stack([J[:, :6], J[:, 0]])):   # full rank; two equal columns (QR way)
        Jc, rc = compress_lsq(JJ, r)
        assert Jc.shape == (8, 7) and rc.shape == (8,)
        np.testing.assert_allclose(Jc.T @ Jc, JJ.T @ JJ, rtol=1e-9, atol=1e-9 * np.abs(JJ.T @ JJ).max())
        np.testing.assert_allclose(Jc.T @ rc, JJ.T @ r, rtol=1e-8, atol=1e-8 * np.abs(JJ.T @ r).max())
        assert abs(rc @ rc - r @ r) < 1e-10 * (r @ r)
        # the same Gauss-Newton step as the full problem
    Jc, rc = compress_lsq(J, r)
    np.testing.assert_allclose(np.linalg.lstsq(Jc, -rc, rcond=None)[0], np.linalg.lstsq(J, -r, rcond=None)[0],
                               rtol=1e-8)


def test_coarse_thrust_grid_follows_the_full_rate_simulation():
    log = simulate("excitation", SimSettings(duration_s=60.0, current_mps=0.2, current_dir_deg=40.0), seed=5)
    run = run_data(log)
    prob = Problem([run], 1e12)
    assert len(prob.tg) < len(run.t_thrust) / 3        # 100 Hz thrust integrated in ~50 ms steps
    th = VesselParams().as_array()
    cur = np.array([[0.15, 0.13]])
    x0 = np.array([[0.0, 0.0, 0.3, 1.0, 0.0, 0.0]])
    coarse, _ = prob.simulate(th, cur, x0, sens=False)
    fine = simulate_run(run, th, cur[0], x0[0], prob.tg[0], prob.meas_t)
    # a 60 s free run: millimetres and hundredths of a degree, against 1.5 m GNSS and 2 deg compass noise
    assert np.abs(coarse[:, :2] - fine[:, :2]).max() < 5e-3
    assert np.abs(coarse[:, 2] - fine[:, 2]).max() < 2e-4
    assert np.abs(fine[:, :2]).max() > 20.0             # the boat did move


def test_savgol_and_lag_are_scipy_signals_bit_for_bit():
    from scipy.signal import lfilter
    from scipy.signal import savgol_filter as scipy_savgol

    rng = np.random.default_rng(5)
    x1 = np.cumsum(rng.normal(size=1001))
    x2 = np.cumsum(rng.normal(size=(801, 3)), axis=0)
    for window, order, deriv, delta in ((21, 3, 0, 1.0), (21, 3, 1, 0.1), (160, 3, 1, 0.1), (7, 2, 2, 0.5),
                                        (5, 3, 4, 1.0)):
        assert np.array_equal(savgol_filter(x1, window, order, deriv=deriv, delta=delta),
                              scipy_savgol(x1, window, order, deriv=deriv, delta=delta, mode="interp"))
        for axis in (0, 1):
            xa = x2 if axis == 0 else x2.T.copy()
            assert np.array_equal(savgol_filter(xa, window, order, deriv=deriv, delta=delta, axis=axis),
                                  scipy_savgol(xa, window, order, deriv=deriv, delta=delta, axis=axis, mode="interp"))
    x32 = x1.astype(np.float32)   # float32 in, float32 out (ndimage sums in float64)
    assert np.array_equal(savgol_filter(x32, 161, 3, deriv=1, delta=0.1),
                          scipy_savgol(x32, 161, 3, deriv=1, delta=0.1, mode="interp"))
    f = rng.normal(size=5000)
    for a in (0.0, 0.3, 0.999):
        assert np.array_equal(_lag(f, a), lfilter([0.0, 1.0], [1.0, -a], f))


def test_identify_with_a_spare_cpu_gives_the_numbers_of_one_thread(monkeypatch):
    """With a spare CPU (USVLOG_THREADS=2) the output-error candidates, fitted one after another,
    integrate their segments in two threads: every candidate, the returned fit and its verdict
    are bit for bit those of everything in one thread (USVLOG_THREADS=1)."""
    from usvlog.identify import Identifier

    log = simulate("excitation", SimSettings(duration_s=150.0, current_mps=0.2, current_dir_deg=60.0), seed=11)
    out = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("USVLOG_THREADS", threads)
        idf = Identifier("output-error", segment_s=60.0).fit([log])
        oe = [c for c in idf.candidates_ if c.start.kind == "output-error"]
        assert len(oe) >= 2 and not any(c.failed for c in oe)
        out[threads] = (repr(idf.to_dict()), [(c.start.name, c.theta.tobytes(), c.currents.tobytes(),
                                               c.score) for c in idf.candidates_], idf.oe_.x0s.tobytes())
    assert out["2"] == out["1"]
