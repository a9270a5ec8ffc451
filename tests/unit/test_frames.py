import math

import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.model.frames import Datum, geodetic_to_ned, ned_to_geodetic, rot, ssa

D = Datum(lat_deg=43.4723, lon_deg=-80.5449)


def test_ssa_wraps_into_half_open_interval():
    a = np.array([0.0, math.pi, -math.pi, 3 * math.pi, 2 * math.pi + 0.1, -0.1 - 4 * math.pi])
    w = ssa(a)
    assert np.all(w >= -math.pi) and np.all(w < math.pi)
    assert np.allclose(np.cos(w), np.cos(a)) and np.allclose(np.sin(w), np.sin(a))
    assert ssa(2 * math.pi + 0.1) == pytest.approx(0.1)


def test_rotation_matches_paper_eq2():
    psi = 0.7
    R = rot(psi)
    expected = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
    assert np.allclose(R, expected)
    # surge at heading 90 deg (east) moves the boat east
    assert np.allclose(rot(math.pi / 2) @ np.array([1.0, 0, 0]), [0, 1, 0], atol=1e-15)


def test_geodetic_round_trip_and_scale():
    n = np.array([0.0, 100.0, -2500.0, 10.0])
    e = np.array([0.0, -50.0, 3000.0, 0.0])
    lat, lon, alt = ned_to_geodetic(n, e, 0.0, datum=D)
    n2, e2, d2 = geodetic_to_ned(lat, lon, alt, datum=D)
    assert np.max(np.abs(n2 - n)) < 1e-6 and np.max(np.abs(e2 - e)) < 1e-6
    # one arc-second of latitude is ~30.9 m at this latitude (WGS-84 meridian radius)
    n1, e1, _ = geodetic_to_ned(D.lat_deg + 1 / 3600, D.lon_deg, 0.0, datum=D)
    assert n1 == pytest.approx(30.87, abs=0.05) and abs(e1) < 1e-6
    # east of the datum at this latitude: cos(lat) shorter
    _, e3, _ = geodetic_to_ned(D.lat_deg, D.lon_deg + 1 / 3600, 0.0, datum=D)
    assert e3 == pytest.approx(30.92 * math.cos(math.radians(D.lat_deg)), rel=2e-3)


def test_datum_range_checked():
    with pytest.raises(ConfigError):
        Datum(lat_deg=93.1, lon_deg=0.0)


def test_wrap_angle_is_ssa_in_python_and_in_kernels():
    from numba import njit

    from usvlog.model.frames import ssa, wrap_angle

    a = np.random.default_rng(4).uniform(-50.0, 50.0, 1000)
    a[:4] = [np.pi, -np.pi, 3 * np.pi, 0.0]

    @njit
    def many(x):
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            out[i] = wrap_angle(x[i])
        return out

    assert np.array_equal(many(a), ssa(a))
    assert np.array_equal(np.array([wrap_angle(float(v)) for v in a]), ssa(a))
    assert ssa(np.pi) == -np.pi and wrap_angle(np.pi) == -np.pi
