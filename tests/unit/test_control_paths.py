import math

import numpy as np
import pytest

from usvlog.control.guidance import closest_point, initial_theta, reference_heading
from usvlog.control.paths import path_from_spec
from usvlog.errors import ConfigError
from usvlog.model.frames import Datum, ned_to_geodetic

SPECS = [
    {"type": "circle", "center_ne": [2.0, -3.0], "radius_m": 4.0, "direction": "cw", "start_deg": 30.0},
    {"type": "circle", "radius_m": 7.5, "direction": "ccw"},
    {"type": "sinusoid", "start_ne": [1.0, 2.0], "direction_deg": 60.0, "amplitude_m": 12.0,
     "period_m": 40.0, "length_m": 160.0},
    {"type": "line", "start_ne": [0.0, 0.0], "direction_deg": -135.0, "length_m": 50.0},
    {"type": "waypoints", "frame": "ned", "points": [[0, 0], [10, 5], [12, 20], [0, 30], [-5, 18]]},
]


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s["type"] + s.get("direction", ""))
def test_derivative_matches_finite_difference(spec):
    p = path_from_spec(spec)
    th = np.linspace(p.theta_min - 3.0, p.theta_max + 3.0, 997)  # includes spline extrapolation
    h = 1e-6
    fd = (p.point(th + h) - p.point(th - h)) / (2 * h)
    assert np.allclose(p.derivative(th), fd, atol=2e-7, rtol=0)
    # the test can fail: a wrong derivative (e.g. the opposite direction) is far off
    assert not np.allclose(-p.derivative(th), fd, atol=1e-3)


def test_circle_geometry_and_direction():
    p = path_from_spec({"type": "circle", "center_ne": [2.0, -3.0], "radius_m": 4.0, "direction": "cw"})
    th = np.linspace(0, 25, 50)
    pts = p.point(th)
    assert np.allclose(np.hypot(pts[:, 0] - 2.0, pts[:, 1] + 3.0), 4.0)
    assert np.allclose(np.hypot(*p.derivative(th).T), 1.0)  # theta is arc length
    # clockwise on a north-up map: from north of the centre the path heads east
    assert np.allclose(p.point(0.0), [6.0, -3.0]) and np.allclose(p.derivative(0.0), [0.0, 1.0])
    q = path_from_spec({"type": "circle", "center_ne": [2.0, -3.0], "radius_m": 4.0, "direction": "ccw"})
    assert np.allclose(q.derivative(0.0), [0.0, -1.0])


def test_spline_passes_through_waypoints_and_is_c1():
    pts = np.array([[0, 0], [10, 5], [12, 20], [0, 30], [-5, 18]], float)
    p = path_from_spec({"type": "waypoints", "points": pts.tolist()})
    knots = np.concatenate([[0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    assert np.allclose(p.point(knots), pts, atol=1e-12)
    eps = 1e-9
    for k in knots[1:-1]:
        assert np.allclose(p.point(k - eps), p.point(k + eps), atol=1e-7)
        assert np.allclose(p.derivative(k - eps), p.derivative(k + eps), atol=1e-6)


def test_latlon_waypoints_match_ned():
    d = Datum(lat_deg=43.47, lon_deg=-80.54)
    ned = np.array([[0.0, 0.0], [30.0, 10.0], [60.0, -20.0]])
    lat, lon, _ = ned_to_geodetic(ned[:, 0], ned[:, 1], 0.0, datum=d)
    p = path_from_spec({"type": "waypoints", "frame": "latlon", "points": np.column_stack([lat, lon]).tolist()},
                       datum=d)
    q = path_from_spec({"type": "waypoints", "points": ned.tolist()})
    th = np.linspace(0, q.theta_max, 50)
    assert np.allclose(p.point(th), q.point(th), atol=1e-6)
    with pytest.raises(ConfigError, match="datum"):
        path_from_spec({"type": "waypoints", "frame": "latlon", "points": [[43.0, -80.0], [43.1, -80.0]]})


@pytest.mark.parametrize("bad,msg", [({"type": "spiral"}, "type"), ({"type": "circle"}, "radius_m"),
                                     ({"type": "circle", "radius_m": -1}, "> 0"),
                                     ({"type": "circle", "radius_m": 4, "dir": "cw"}, "unknown"),
                                     ({"type": "waypoints", "points": [[0, 0], [0, 0]]}, "coincide")])
def test_bad_specs_name_the_problem(bad, msg):
    with pytest.raises(ConfigError, match=msg):
        path_from_spec(bad, source="x.toml")


def test_descent_finds_the_geometric_closest_point_of_a_circle():
    p = path_from_spec({"type": "circle", "center_ne": [1.0, 2.0], "radius_m": 4.0, "direction": "ccw"})
    rng = np.random.default_rng(0)
    for _ in range(50):
        rho = rng.uniform(0.5, 7.5)   # gamma R / rho < 2 for convergence: gamma = 0.5
        ang = rng.uniform(-np.pi, np.pi)
        n, e = 1.0 + rho * math.cos(ang), 2.0 + rho * math.sin(ang)
        true = np.array([1.0 + 4 * math.cos(ang), 2.0 + 4 * math.sin(ang)])
        th0 = initial_theta(p, n, e, samples=16) + rng.uniform(-0.5, 0.5)  # a rough start
        th = closest_point(p, n, e, th0, gamma=0.5, iterations=200)
        assert np.allclose(p.point(th), true, atol=1e-9)


def test_descent_finds_the_closest_point_of_a_sinusoid_by_dense_search():
    p = path_from_spec({"type": "sinusoid", "direction_deg": 90.0, "amplitude_m": 12.0, "period_m": 40.0,
                        "length_m": 160.0})
    grid = np.linspace(-20, 180, 2_000_001)
    dense = p.point(grid)
    rng = np.random.default_rng(1)
    for _ in range(30):
        n, e = rng.uniform(-15, 15), rng.uniform(5, 150)
        d2 = (dense[:, 0] - n) ** 2 + (dense[:, 1] - e) ** 2
        th_true = grid[np.argmin(d2)]
        # |p_d'|^2 <= 1 + (2 pi A / P)^2 = 4.55: gamma = 0.2 keeps gamma J'' < 2
        th = closest_point(p, n, e, initial_theta(p, n, e), gamma=0.2, iterations=200)
        assert abs(th - th_true) < 2e-4
        assert np.hypot(*(p.point(th) - [n, e])) <= math.sqrt(d2.min()) + 1e-9


def test_reference_heading_is_eq8_in_ned():
    p = path_from_spec({"type": "line", "start_ne": [0.0, 0.0], "direction_deg": 0.0, "length_m": 100.0})
    # boat 3 m east of a north-going line: carrot 4 m ahead -> atan2(-3, 4)
    assert reference_heading(p, 0.0, 3.0, 0.0, 4.0) == pytest.approx(math.atan2(-3.0, 4.0))
    assert reference_heading(p, 0.0, -3.0, 0.0, 4.0) == pytest.approx(math.atan2(3.0, 4.0))
