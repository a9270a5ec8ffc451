"""The identification's numerical functions never end in a raw numpy/scipy exception.

Each function is driven over starting guesses from a tenth to ten times sensible values (and
some that are no boat at all), over short and badly excited runs and over degenerate inputs
(too few samples, NaN, empty segments, overflowing numbers). Every case ends either in a finite
result or in :class:`usvlog.errors.FitFailed` / another :class:`usvlog.errors.UsvlogError` with a
message: never an IndexError, LinAlgError, ValueError or ZeroDivisionError from inside.

The crashes this guards against were found on logs of Fossen's Otter catamaran with such starts:
``np.add.reduceat`` on empty shooting segments, an overflow in the output-error fit's
compression of its Jacobian (``eigvalsh``: eigenvalues did not converge), and a Savitzky-Golay
window from a NaN sample spacing (``int(nan)``).
"""

from __future__ import annotations

import gzip
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from usvlog.errors import FitFailed, UnusableResultError, UsvlogError
from usvlog.identify.data import run_data
from usvlog.identify.equation import fit_equation_error
from usvlog.identify.extended_oe import fit_extended_output_error, fit_initial_state_ext, free_run_full
from usvlog.identify.output import (
    Problem,
    compress_lsq,
    fit_initial_state,
    fit_output_error,
    simulate_run,
)
from usvlog.identify.smooth import derivative, savgol_states, smooth_like
from usvlog.identify.surge import fit_surge
from usvlog.model.vessel import ExtendedParams, VesselParams, default_vessel
from usvlog.sim.simulate import SimSettings, simulate

SCALES = (0.1, 0.3, 3.0, 10.0)
TRAINLOGS = Path(__file__).resolve().parents[3] / "shared" / "trainlogs"


def _sensible() -> np.ndarray:
    return default_vessel().params.as_array()


def _starts():
    """Starts from 0.1x to 10x the paper's vessel: all scaled, inertia and damping apart."""
    th = _sensible()
    out = []
    for s in SCALES:
        out.append(th * s)
        a = th.copy()
        a[:2] *= s          # inertia scaled, damping not
        out.append(a)
        b = th.copy()
        b[2:5] *= s         # damping scaled, inertia not
        out.append(b)
    return out


@pytest.fixture(scope="module")
def short_run():
    """A 40 s excitation run of the paper's vessel: (RunData, smoothed states)."""
    log = simulate("excitation", SimSettings(duration_s=40.0), seed=11)
    run = run_data(log)
    return run, savgol_states(run)


@pytest.fixture(scope="module")
def straight_run():
    """A badly excited run: 30 s straight ahead, no yaw excitation at all."""
    log = simulate("straight", SimSettings(duration_s=30.0), seed=12)
    run = run_data(log)
    return run, savgol_states(run)


def _finite_or_failed(fn, *args, **kw):
    """fn's result, or None when it raised a UsvlogError (with a message); any other exception
    propagates and fails the test."""
    try:
        return fn(*args, **kw)
    except UsvlogError as err:
        assert str(err).strip(), type(err)
        return None


def _oe_ok(res) -> bool:
    """FitFailed with its reason (None), or a fit whose values are all finite and whose covariance
    matches its names: never another exception."""
    return res is None or bool(np.all(np.isfinite(res.theta)) and np.all(np.isfinite(res.currents))
                               and res.cov.shape == (len(res.names), len(res.names)))


def test_fit_failed_is_an_unusable_result_with_its_reason():
    err = FitFailed("its simulation diverged")
    assert isinstance(err, UnusableResultError) and isinstance(err, ArithmeticError)
    assert err.exit_code == 1 and err.reasons == ["its simulation diverged"]


@pytest.mark.parametrize("k", range(len(SCALES) * 3))
def test_output_error_from_any_start(short_run, k):
    run, ks = short_run
    th0 = _starts()[k]
    res = _finite_or_failed(fit_output_error, [run], th0, lambda i, t: ks.at(t), segment_s=20.0,
                            warm_segment_s=10.0, max_nfev=8, max_current_mps=0.5)
    assert _oe_ok(res), res


@pytest.mark.parametrize("scale", [0.1, 10.0])
def test_output_error_on_a_badly_excited_run(straight_run, scale):
    run, ks = straight_run
    res = _finite_or_failed(fit_output_error, [run], _sensible() * scale, lambda i, t: ks.at(t), segment_s=15.0,
                            warm_segment_s=0.0, max_nfev=8, max_current_mps=0.5)
    assert _oe_ok(res), res


def test_output_error_refuses_what_cannot_be_fitted(short_run):
    run, ks = short_run
    with pytest.raises(FitFailed, match="finite"):
        fit_output_error([run], [np.nan, 1, 1, 1, 1, 0], lambda i, t: ks.at(t))
    tiny = run.window(5.0, 5.0)   # one thrust sample at most: nothing to integrate
    with pytest.raises(FitFailed, match="thrust"):
        fit_output_error([tiny], _sensible(), lambda i, t: ks.at(t))
    no_meas = replace(run, t_gps=run.t_gps[:0], n_gps=run.n_gps[:0], e_gps=run.e_gps[:0],
                      sigma_gps=run.sigma_gps[:0], t_compass=run.t_compass[:0], psi_compass=run.psi_compass[:0],
                      sigma_compass=run.sigma_compass[:0])
    with pytest.raises(FitFailed, match="nothing to fit"):
        fit_output_error([no_meas], _sensible(), lambda i, t: ks.at(t), warm_segment_s=0.0)


def test_segments_without_measurements_sum_to_zero(short_run):
    """A gap in the GNSS and compass leaves shooting segments without residual rows (inside and
    at the end): their sums are zero and the others' unchanged (reduceat alone fails or lies)."""
    run, ks = short_run
    keep_g, keep_c = run.t_gps < 12.0, run.t_compass < 12.0
    gap = replace(run, t_gps=run.t_gps[keep_g], n_gps=run.n_gps[keep_g], e_gps=run.e_gps[keep_g],
                  sigma_gps=run.sigma_gps[keep_g], t_compass=run.t_compass[keep_c],
                  psi_compass=run.psi_compass[keep_c], sigma_compass=run.sigma_compass[keep_c])
    prob = Problem([gap], 5.0)
    assert prob.n_seg >= 6 and np.any(np.diff(prob.r_start) == 0)
    a = np.arange(prob.n_res, dtype=float) + 1.0
    expect = np.bincount(prob.r_seg, a, minlength=prob.n_seg)
    np.testing.assert_array_equal(prob.seg_sum(a), expect)
    np.testing.assert_array_equal(prob.seg_sum(np.stack([a, 2 * a], 1)), np.stack([expect, 2 * expect], 1))
    # and the fit over that run ends (segments without data keep their start)
    assert _oe_ok(_finite_or_failed(fit_output_error, [gap], _sensible(), lambda i, t: ks.at(t), segment_s=5.0,
                                    warm_segment_s=0.0, max_nfev=5))


def test_compression_of_overflowing_numbers():
    """[J r] whose Gram matrix overflows: the same factor from the column-scaled problem; not finite: FitFailed."""
    rng = np.random.default_rng(0)
    J = rng.normal(size=(50, 3))
    r = rng.normal(size=50)
    Jc, rc = compress_lsq(J, r)
    big = 1e170
    Jb, rb = compress_lsq(J * big, r)
    assert np.all(np.isfinite(Jb)) and np.all(np.isfinite(rb))
    np.testing.assert_allclose(np.abs(Jb / big), np.abs(Jc), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Jb.T @ rb / big, J.T @ r, rtol=1e-9)
    J[3, 1] = np.inf
    with pytest.raises(FitFailed):
        compress_lsq(J, r)


BAD_THETAS = [np.array([0.0, 1.0, 1.0, 1.0, 1.0, 0.0]), np.array([30.0, 1.0, 4.0, 4.0, 4.0, 1.0]),
              np.array([np.nan, 8.0, 4.0, 4.0, 4.0, 0.0]), np.array([-30.0, 8.0, 4.0, 4.0, 4.0, 0.0])]


@pytest.mark.parametrize("theta", [*(_sensible() * s for s in SCALES), *BAD_THETAS])
def test_validation_free_run_from_any_parameters(short_run, theta):
    """fit_initial_state then simulate_run: a state and NaN-or-finite rows, or FitFailed (no boat)."""
    run, ks = short_run
    for fit_current in (True, False):
        out = _finite_or_failed(fit_initial_state, run, theta, ks.at(1.0), 1.0, 15.0, fit_current=fit_current)
        if out is not None:
            x0, cur = out
            assert x0.shape == (6,) and cur.shape == (2,)
    t = ks.t[ks.t >= 1.0]
    sim = simulate_run(run, theta, (0.0, 0.0), ks.at(1.0), 1.0, t)
    assert sim.shape == (len(t), 6)
    assert not np.isinf(sim).any()   # finite, or NaN where it diverged / cannot be simulated


def test_validation_window_without_thrust(short_run):
    run, ks = short_run
    with pytest.raises(FitFailed, match="thrust"):
        fit_initial_state(run, _sensible(), ks.at(1.0), 100.0, 120.0)


@pytest.mark.parametrize("scale", [*SCALES, 1.0])
def test_surge_fit_from_any_start(short_run, scale):
    run, ks = short_run
    th = _sensible()
    sf = _finite_or_failed(fit_surge, [run], [ks], th[0] * scale, th[2] * scale, 0.0, max_current_mps=0.5)
    if sf is not None:
        assert math.isfinite(sf.m) and math.isfinite(sf.d11) and sf.m > 0 and sf.d11 > 0


def test_surge_fit_refuses_a_start_that_is_no_boat(short_run):
    run, ks = short_run
    with pytest.raises(FitFailed, match="start"):
        fit_surge([run], [ks], 0.0, 4.0)
    with pytest.raises(FitFailed, match="start"):
        fit_surge([run], [ks], float("nan"), 4.0)


@pytest.mark.parametrize("scale", [0.1, 10.0])
def test_extended_output_error_from_any_start(short_run, scale):
    run, ks = short_run
    p = _sensible()
    p[:5] *= scale   # (xg is a length: the same boat, heavier or lighter)
    th = ExtendedParams.from_paper(VesselParams(**dict(zip(("m", "Iz", "d11", "d22", "d33", "xg"),
                                                           map(float, p))))).as_array()
    res = _finite_or_failed(fit_extended_output_error, [run], [ks], th, segment_s=20.0, max_iter=3)
    if res is not None:
        assert np.all(np.isfinite(res.theta)) and np.all(np.isfinite(res.currents))
    with pytest.raises(FitFailed):
        fit_extended_output_error([run], [ks], th * np.nan, max_iter=2)


def test_extended_free_run_of_no_boat(short_run):
    run, ks = short_run
    th = np.zeros(10)   # m11 = 0: the dynamics divide by it
    sim = free_run_full(run, th, (0.0, 0.0), ks.at(1.0), 1.0, ks.t[ks.t >= 1.0])
    assert np.isnan(sim).all()
    with pytest.raises(FitFailed, match="not positive"):
        fit_initial_state_ext(run, th, ks.at(1.0), 1.0, 10.0, (0.0, 0.0))


@pytest.mark.parametrize("n", [0, 1, 2, 4])
def test_smoothing_too_few_samples_is_fit_failed(n):
    t = np.arange(n) * 0.1
    y = np.ones((n, 3))
    for fn in (derivative, smooth_like):
        with pytest.raises(FitFailed, match="too short"):
            fn(t, y, 2.0)


def test_smoothing_five_samples_and_a_stuck_clock():
    t = np.arange(5) * 0.1
    assert derivative(t, t, 2.0) == pytest.approx(np.ones(5))
    with pytest.raises(FitFailed, match="not increasing"):
        smooth_like(np.zeros(8), np.ones(8), 2.0)


def test_smoothed_states_of_a_run_too_short(short_run):
    run, ks = short_run
    with pytest.raises(FitFailed):
        savgol_states(run.window(0.0, 0.2))
    # a held-out part the GNSS and compass do not cover (they stopped, the thrust log went on)
    with pytest.raises(FitFailed, match="do not cover"):
        ks.window(ks.t[-1] + 1.0, np.inf)
    assert len(ks.window(-np.inf, 10.0).t) > 50


def test_equation_error_degenerate_inputs(short_run, straight_run):
    # no motion at all: every regressor and force zero (each equation fits exactly)
    z = np.zeros((200, 3))
    ee = fit_equation_error(z, z, np.zeros(200), np.zeros(200))
    assert ee.theta.shape == (6,)
    # NaN gaps are left out; too few finite samples: FitFailed
    nu = np.random.default_rng(1).normal(size=(200, 3))
    nu[::3] = np.nan
    ee = fit_equation_error(nu, nu, np.ones(200), np.ones(200))
    assert np.isfinite(ee.rms).all()
    with pytest.raises(FitFailed, match="too few"):
        fit_equation_error(nu[:5], nu[:5], 1.0, 1.0)
    # a badly excited run: a result (perhaps no boat: ``valid`` says so), not an exception
    run, ks = straight_run
    nu = ks.nu()
    ee = fit_equation_error(smooth_like(ks.t, nu), derivative(ks.t, nu), 100.0, 0.0)
    assert ee.theta.shape == (6,)


def _otter_piece(tmp_path, t0: float, t1: float):
    """[t0, t1) s of the shared Otter run a, imported in memory (None when the logs are absent)."""
    src = TRAINLOGS / "otter_train_a_sensor.csv.gz"
    if not src.exists():
        pytest.skip(f"the shared Otter runs are not here ({TRAINLOGS})")
    from usvlog.api import import_log
    from usvlog.model.vessel import vessel_from_toml

    with gzip.open(src, "rt") as f:
        df = pd.read_csv(f, nrows=int(t1 * 100) + 10)
    df = df[(df.t >= t0) & (df.t < t1)].copy()
    df["t"] -= t0
    csv = tmp_path / "otter_piece.csv"
    df.to_csv(csv, index=False)
    vessel = vessel_from_toml('name = "otter-guess"\n[model]\nm = 30.0\nIz = 8.0\nd11 = 4.0\nd22 = 4.0\n'
                              'd33 = 4.0\nxg = 0.0\n[thrusters]\narm_m = 0.395\nmap = "identity"\n'
                              'forward_n = 150.0\nreverse_n = 100.0\n')
    cols = {"time_s": "t", "lat_deg": "lat_deg", "lon_deg": "lon_deg", "heading_deg": "heading_deg",
            "thrust_left": "thrust_cmd_left_N", "thrust_right": "thrust_cmd_right_N"}
    res = import_log(csv, fmt="csv", vessel=vessel, columns=cols, thrust_unit="newton",
                     start_utc="2026-06-01T12:00:00Z")
    return res.log, vessel


@pytest.mark.parametrize("scale", [0.1, 10.0])
def test_a_piece_of_the_otter_run(tmp_path, scale):
    """40 s of a foreign hull's zig-zag from the paper's scale x0.1 and x10 (the crash of x0.1
    was an overflow in the Jacobian's compression)."""
    log, vessel = _otter_piece(tmp_path, 150.0, 190.0)
    run = run_data(log, vessel)
    ks = savgol_states(run)
    th0 = np.array([30.0, 8.0, 4.0, 4.0, 4.0, 0.0]) * scale
    assert _oe_ok(_finite_or_failed(fit_output_error, [run], th0, lambda i, t: ks.at(t), segment_s=20.0,
                                    warm_segment_s=10.0, max_nfev=10, max_current_mps=0.5,
                                    velocities=None))
    sf = _finite_or_failed(fit_surge, [run], [ks], th0[0], th0[2], 0.0, max_current_mps=0.5)
    assert sf is None or (math.isfinite(sf.m) and math.isfinite(sf.d11))


def test_a_candidate_too_stiff_to_simulate_is_a_failed_one():
    """A parameter vector whose velocities decay in under 20 ms (an equation-error fit on a hull
    it does not describe: m a few grams) is no boat: refused with the reason before any free run,
    whose integration steps would otherwise shrink without end."""
    from usvlog.identify.candidates import physical_problem

    assert physical_problem([33.0, 10.0, 5.0, 5.0, 5.0, 0.1]) == ""
    why = physical_problem([0.004, 10.0, 5.0, 5.0, 5.0, 0.0])   # d11 / m = 1250 /s
    assert "time constant" in why and "no boat" in why, why
