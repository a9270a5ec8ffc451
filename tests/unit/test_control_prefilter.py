import math

import numpy as np

from usvlog.control.prefilter import filter_heading, filter_surge


def test_heading_model_step_response_is_fossens_third_order():
    w, dt = 0.8, 1e-3
    t = np.arange(0, 20, dt)
    out = filter_heading(np.full(len(t), 0.5), dt, omega=w, zeta=1.0, psi0=0.0)
    # zeta = 1: w^3 / (s + w)^3, step response 1 - e^{-wt} (1 + wt + (wt)^2 / 2)
    wt = w * t
    exact = 0.5 * (1 - np.exp(-wt) * (1 + wt + wt**2 / 2))
    assert np.max(np.abs(out[:, 0] - exact)) < 2e-4
    # r_d and r_d_dot are the derivatives of psi_d and r_d
    assert np.allclose(np.diff(out[:, 0]) / dt, out[:-1, 1], atol=1e-12)
    assert np.allclose(np.diff(out[:, 1]) / dt, out[:-1, 2], atol=1e-12)


def test_heading_model_crosses_pi_the_short_way():
    dt = 0.01
    t = np.arange(0, 30, dt)
    ref = np.full(len(t), math.radians(179.0))
    out = filter_heading(ref, dt, omega=1.0, psi0=math.radians(-179.0))
    # psi_d moves 2 degrees through +-180 (negative rate), not 358 degrees the long way
    assert np.all(out[:, 1] <= 1e-12)
    total = np.sum(out[:-1, 1]) * dt
    assert abs(math.degrees(total) + 2.0) < 0.01
    assert abs(math.degrees(out[-1, 0]) - 179.0) < 0.01
    # the reference itself wrapping (a small turn across north-south) gives no jump either
    ref2 = np.unwrap(np.linspace(math.radians(170), math.radians(190), len(t)))
    ref2 = (ref2 + np.pi) % (2 * np.pi) - np.pi
    out2 = filter_heading(ref2, dt, omega=1.0)
    assert np.max(np.abs(out2[:, 1])) < math.radians(20) / 30 * 1.5


def test_surge_models():
    w, dt = 0.5, 1e-3
    t = np.arange(0, 30, dt)
    ref = np.where(t < 1.0, 0.1, 0.2)
    o2 = filter_surge(ref, dt, order=2, omega=w, zeta=1.0)
    tt = np.clip(t - 1.0, 0, None)
    exact = 0.1 + 0.1 * (1 - np.exp(-w * tt) * (1 + w * tt))
    assert np.max(np.abs(o2[:, 0] - exact)) < 2e-4
    assert np.allclose(np.diff(o2[:, 0]) / dt, o2[:-1, 1], atol=1e-12)
    o1 = filter_surge(ref, dt, order=1, omega=w)
    assert np.max(np.abs(o1[:, 0] - (0.1 + 0.1 * (1 - np.exp(-w * tt))))) < 2e-4
    assert np.allclose(np.diff(o1[:, 0]) / dt, o1[:-1, 1], atol=1e-12)
    o0 = filter_surge(ref, dt, order=0)
    assert np.array_equal(o0[:, 0], ref) and np.all(o0[:, 1] == 0)
