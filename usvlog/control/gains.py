"""Controller gains, guidance settings and the gain check of Theorem 3.1 / 3.2.

TOML (a gains file, or the same tables inside a scenario file)::

    [gains]            # the paper's symbols
    KPu = 5.0
    KIu = 0.5
    KPpsi = 5.0
    KIpsi = 0.1
    KDpsi = 1.0

    [guidance]
    delta_theta = 1.0        # carrot, metres along the path
    gamma = 0.5              # gradient-descent step of (7)
    iterations = 10          # descent iterations per controller tick
    rate_hz = 100.0          # controller rate
    psi_omega = 0.5          # heading reference model natural frequency, rad/s
    psi_zeta = 1.0
    surge_order = 2          # 0 (none), 1 or 2
    u_omega = 0.5            # surge reference model natural frequency, rad/s
    u_zeta = 1.0
    prefilter_init = "reference"   # or "state": start the filters at the vessel's heading/speed
    anti_windup = true       # conditional integration while the thrusters saturate
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..errors import ConfigError
from ..model.vessel import VesselParams, require_finite

GAIN_NAMES = ("KPu", "KIu", "KPpsi", "KIpsi", "KDpsi")


@dataclass(frozen=True, kw_only=True)
class Gains:
    """Gains of control law (9)-(10), paper symbols (the Section IV values by default).

    tau_u = -KPu ue - KIu int(ue) + ... and tau_r = -KPpsi psie - KIpsi int(psie) -
    KDpsi re + ..., with ue in m/s, psie in rad and re in rad/s (see
    :mod:`usvlog.control.law`). All gains are finite and >= 0.

    Parameters
    ----------
    KPu : float, default 5.0
        Surge proportional gain, N per m/s (N s/m).
    KIu : float, default 0.5
        Surge integral gain, N per m (N/m).
    KPpsi : float, default 5.0
        Heading proportional gain, N m/rad.
    KIpsi : float, default 0.1
        Heading integral gain, N m/(rad s).
    KDpsi : float, default 1.0
        Heading derivative gain (on the yaw-rate error), N m s/rad.

    Raises
    ------
    usvlog.errors.ConfigError
        If a gain is not a finite number or is negative.

    See Also
    --------
    check_gains : the conditions of Theorems 3.1 and 3.2 for these gains and a vessel.
    """

    KPu: float = 5.0
    KIu: float = 0.5
    KPpsi: float = 5.0
    KIpsi: float = 0.1
    KDpsi: float = 1.0

    def __post_init__(self):
        require_finite(self, GAIN_NAMES, "gain")
        for f in GAIN_NAMES:
            if getattr(self, f) < 0:
                raise ConfigError(f"gain {f} = {getattr(self, f)} must be >= 0")

    def as_array(self) -> np.ndarray:
        """Gains as a float array of shape (5,): KPu, KIu, KPpsi, KIpsi, KDpsi (``GAIN_NAMES``)."""
        return np.array([getattr(self, f) for f in GAIN_NAMES], dtype=float)

    def to_dict(self) -> dict[str, float]:
        """Gains by paper symbol as Python floats (the ``[gains]`` table)."""
        return {f: float(getattr(self, f)) for f in GAIN_NAMES}


@dataclass(frozen=True, kw_only=True)
class GuidanceSettings:
    """Guidance (7)-(8), prefilters and controller rate.

    Parameters
    ----------
    delta_theta : float, default 1.0
        Carrot distance ahead of the closest point along the path, m (> 0).
    gamma : float, default 0.5
        Step of the gradient descent (7), dimensionless (> 0; see :mod:`usvlog.control.guidance`
        for convergence).
    iterations : int, default 10
        Descent iterations per controller tick, >= 1.
    rate_hz : float, default 100.0
        Controller rate, Hz.
    psi_omega : float, default 0.5
        Natural frequency of the heading reference model, rad/s.
    psi_zeta : float, default 1.0
        Its relative damping.
    surge_order : {0, 1, 2}, default 2
        Order of the surge reference model (0: none, u_d = u_ref).
    u_omega : float, default 0.5
        Natural frequency of the surge reference model, rad/s.
    u_zeta : float, default 1.0
        Its relative damping (order 2).
    prefilter_init : {"reference", "state"}, default "reference"
        Start the prefilters at the reference, or at the vessel's heading and speed.
    anti_windup : bool, default True
        Conditional integration while the thrusters saturate.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not a positive finite number or not one of the allowed choices.
    """

    delta_theta: float = 1.0
    gamma: float = 0.5
    iterations: int = 10
    rate_hz: float = 100.0
    psi_omega: float = 0.5
    psi_zeta: float = 1.0
    surge_order: int = 2
    u_omega: float = 0.5
    u_zeta: float = 1.0
    prefilter_init: str = "reference"
    anti_windup: bool = True

    def __post_init__(self):
        for f in ("delta_theta", "gamma", "rate_hz", "psi_omega", "psi_zeta", "u_omega", "u_zeta"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ConfigError(f"guidance setting {f} = {v!r} must be a finite number > 0")
        if not isinstance(self.iterations, int) or isinstance(self.iterations, bool) or self.iterations < 1:
            raise ConfigError(f"guidance setting iterations = {self.iterations!r} must be an integer >= 1")
        if self.surge_order not in (0, 1, 2):
            raise ConfigError(f"guidance setting surge_order = {self.surge_order!r} must be 0, 1 or 2")
        if self.prefilter_init not in ("reference", "state"):
            raise ConfigError(f"guidance setting prefilter_init = {self.prefilter_init!r} must be reference or state")
        if not isinstance(self.anti_windup, bool):
            raise ConfigError("guidance setting anti_windup must be true or false")

    def to_dict(self) -> dict:
        """All fields by name (the ``[guidance]`` table)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def gains_from_dict(doc: dict, source: str = "gains") -> tuple[Gains, GuidanceSettings]:
    """Read ``[gains]`` and ``[guidance]`` from a parsed TOML document.

    Parameters
    ----------
    doc : dict
        Parsed TOML with a ``[gains]`` table and an optional ``[guidance]`` table
        (missing keys take the defaults).
    source : str, default "gains"
        Name of the document, for error messages.

    Returns
    -------
    gains : Gains
    guidance : GuidanceSettings

    Raises
    ------
    usvlog.errors.ConfigError
        If ``[gains]`` is missing, a table has an unknown key or a value is out of range.
    """
    g = doc.get("gains")
    if g is None:
        raise ConfigError(f"{source}: no [gains] table")
    unknown = set(g) - set(GAIN_NAMES)
    if unknown:
        raise ConfigError(f"{source}: [gains] has unknown key(s) {', '.join(sorted(unknown))} "
                          f"(expected {', '.join(GAIN_NAMES)})")
    gd = doc.get("guidance", {})
    known = {f.name for f in fields(GuidanceSettings)}
    unknown = set(gd) - known
    if unknown:
        raise ConfigError(f"{source}: [guidance] has unknown key(s) {', '.join(sorted(unknown))}")
    try:
        gains = Gains(**g)
        guid = GuidanceSettings(**gd)
    except (ConfigError, TypeError) as err:
        raise ConfigError(f"{source}: {err}") from err
    return gains, guid


# -----------------------------------------------------------------------------
# Theorem 3.1 / 3.2
# -----------------------------------------------------------------------------

def error_matrix(p: VesselParams, g: Gains) -> np.ndarray:
    """A_e of (12), exactly as printed in the paper; state x_e = [ueI, ue, psieI, psie, re, v].

    Parameters
    ----------
    p : VesselParams
    g : Gains

    Returns
    -------
    numpy.ndarray, shape (6, 6)
        Closed-loop error-dynamics matrix (x_e_dot = A_e x_e); divides by
        Iz - m xg^2, so that must be non-zero.
    """
    m, Iz, d11, d22, d33, xg = p.m, p.Iz, p.d11, p.d22, p.d33, p.xg
    J = Iz - m * xg**2
    A = np.zeros((6, 6))
    A[0, 1] = 1.0
    A[1, 0] = -g.KIu / m
    A[1, 1] = -(g.KPu + d11) / m
    A[2, 3] = 1.0
    A[3, 4] = 1.0
    A[4, 2] = -g.KIpsi / J
    A[4, 3] = -g.KPpsi / J
    A[4, 4] = -(g.KDpsi + d33) / J
    A[5, 2] = xg * g.KIpsi / J
    A[5, 3] = xg * g.KPpsi / J
    A[5, 4] = xg * (g.KDpsi + d33) / J
    A[5, 5] = -d22 / m
    return A


@dataclass(frozen=True)
class Condition:
    """One condition of Theorem 3.1: its name, the expression, its value and whether it holds."""

    name: str
    expression: str
    value: float
    holds: bool

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return {"name": self.name, "expression": self.expression, "value": self.value, "holds": self.holds}


@dataclass(frozen=True)
class GainCheck:
    """Verdict of Theorem 3.1 (conditions, A_e, eigenvalues) and Theorem 3.2 (bound (18)).

    Attributes
    ----------
    params : VesselParams
    gains : Gains
    conditions : tuple of Condition
        The three conditions of Theorem 3.1 (condition 2 as two entries).
    A_e : numpy.ndarray, shape (6, 6)
        Error-dynamics matrix of (12) (NaN when Iz - m xg^2 = 0).
    eigenvalues : numpy.ndarray of complex, shape (6,)
        Eigenvalues of A_e, 1/s.
    hurwitz : bool
        All eigenvalues have negative real parts.
    Q : numpy.ndarray, shape (6, 6)
        Right-hand side of the Lyapunov equation P A_e + A_e^T P = -Q.
    P : numpy.ndarray or None
        Its solution (None unless A_e is Hurwitz).
    c1, c2, c3, c4 : float or None
        lambda_min(P), lambda_max(P), lambda_min(Q), 2 lambda_max(P) (None unless Hurwitz).
    delta : float or None
        Bound on the disturbance term given to :func:`check_gains`.
    theta : float
        The theta in (0, 1) of the bound.
    bound_per_delta : float or None
        Ultimate bound (18) of |x_e| per unit of delta.
    bound : float or None
        bound_per_delta * delta (None without delta).
    """

    params: VesselParams
    gains: Gains
    conditions: tuple[Condition, ...]
    A_e: np.ndarray
    eigenvalues: np.ndarray
    hurwitz: bool
    Q: np.ndarray
    P: np.ndarray | None
    c1: float | None
    c2: float | None
    c3: float | None
    c4: float | None
    delta: float | None
    theta: float
    bound_per_delta: float | None
    bound: float | None

    @property
    def ok(self) -> bool:
        """All conditions hold and A_e is Hurwitz."""
        return all(c.holds for c in self.conditions) and self.hurwitz

    @property
    def failed(self) -> list[str]:
        """One line per failed condition (and for a non-Hurwitz A_e); empty when :attr:`ok`."""
        out = [f"{c.name} ({c.expression} = {c.value:.6g})" for c in self.conditions if not c.holds]
        if not self.hurwitz:
            worst = float(np.max(self.eigenvalues.real))
            out.append(f"A_e is not Hurwitz (largest real part of an eigenvalue {worst:.6g})")
        return out

    @property
    def verdict(self) -> str:
        """One-line verdict starting with ``OK:`` or ``FAIL:``."""
        if self.ok:
            return "OK: all conditions of Theorem 3.1 hold, A_e is Hurwitz, v is ultimately bounded"
        return "FAIL: " + "; ".join(self.failed)

    def to_dict(self) -> dict:
        """JSON-ready dict of every field plus ``ok`` and ``verdict`` (eigenvalues as re/im pairs)."""
        ev = self.eigenvalues
        return {"ok": self.ok, "verdict": self.verdict, "params": self.params.to_dict(),
                "gains": self.gains.to_dict(),
                "conditions": [c.to_dict() for c in self.conditions],
                "A_e": self.A_e.tolist(),
                "eigenvalues": [{"re": float(z.real), "im": float(z.imag)} for z in ev],
                "hurwitz": self.hurwitz, "Q": self.Q.tolist(),
                "P": None if self.P is None else self.P.tolist(),
                "c1": self.c1, "c2": self.c2, "c3": self.c3, "c4": self.c4,
                "delta": self.delta, "theta": self.theta,
                "bound_per_delta": self.bound_per_delta, "bound": self.bound}


def check_gains(params: VesselParams, gains: Gains, *, Q=None, delta: float | None = None,
                theta: float = 0.5) -> GainCheck:
    """Theorem 3.1's three conditions, eig(A_e), and the ultimate bound (18) for P A_e + A_e^T P = -Q.

    Parameters
    ----------
    params : VesselParams
        Vessel model parameters (SI units).
    gains : Gains
    Q : array_like, optional
        Symmetric positive definite (6, 6) matrix, or its 6 diagonal entries (default
        the identity).
    delta : float, optional
        Bound (>= 0) on the disturbance of the error dynamics; gives ``bound``.
    theta : float, default 0.5
        The theta in (0, 1) of Theorem 3.2.

    Returns
    -------
    GainCheck

    Raises
    ------
    usvlog.errors.ConfigError
        If ``theta``, ``delta`` or ``Q`` is out of range.
    """
    from scipy.linalg import solve_continuous_lyapunov

    if not (0 < theta < 1):
        raise ConfigError(f"theta = {theta} must be in (0, 1)")
    if delta is not None and not (math.isfinite(delta) and delta >= 0):
        raise ConfigError(f"delta = {delta} must be a finite number >= 0")
    p, g = params, gains
    J = p.Iz - p.m * p.xg**2
    c1 = J
    c2a, c2b = g.KIu, g.KPu + p.d11
    c3 = g.KPpsi * (p.d33 + g.KDpsi) - g.KIpsi * J
    conds = (
        Condition("condition 1", "Iz - m xg^2 > 0", float(c1), bool(c1 > 0)),
        Condition("condition 2", "KIu > 0", float(c2a), bool(c2a > 0)),
        Condition("condition 2", "KPu + d11 > 0", float(c2b), bool(c2b > 0)),
        Condition("condition 3", "KPpsi (d33 + KDpsi) - KIpsi (Iz - m xg^2) > 0", float(c3), bool(c3 > 0)),
    )
    A = error_matrix(p, g) if J != 0 else np.full((6, 6), np.nan)
    Qm = np.eye(6) if Q is None else np.asarray(Q, dtype=float)
    if Qm.ndim == 1:
        Qm = np.diag(Qm)
    if Qm.shape != (6, 6) or not np.allclose(Qm, Qm.T) or np.linalg.eigvalsh(Qm).min() <= 0:
        raise ConfigError("Q must be a symmetric positive definite 6x6 matrix (or 6 diagonal entries)")
    ev = np.linalg.eigvals(A) if np.all(np.isfinite(A)) else np.full(6, np.nan + 0j)
    hurwitz = bool(np.all(np.isfinite(ev)) and np.max(ev.real) < 0)
    P = k1 = k2 = k3 = k4 = bpd = b = None
    if hurwitz:
        # scipy solves A X + X A^H = Q; with A -> A_e^T this is A_e^T P + P A_e = -Q
        P = solve_continuous_lyapunov(A.T, -Qm)
        P = 0.5 * (P + P.T)
        lp = np.linalg.eigvalsh(P)
        lq = np.linalg.eigvalsh(Qm)
        k1, k2, k3, k4 = float(lp.min()), float(lp.max()), float(lq.min()), float(2 * lp.max())
        bpd = float(2 * k2 / k3 * math.sqrt(k2 / k1) / theta)
        b = None if delta is None else bpd * delta
    return GainCheck(p, g, conds, A, ev, hurwitz, Qm, P, k1, k2, k3, k4, delta, float(theta), bpd, b)


__all__ = ["Gains", "GuidanceSettings", "gains_from_dict", "error_matrix", "check_gains", "GainCheck",
           "Condition", "GAIN_NAMES"]
