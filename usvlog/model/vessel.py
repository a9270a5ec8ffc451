"""The paper's 3-DOF vessel: parameters, thruster geometry and map, dynamics (1)-(6).

Pure functions of arrays. ``nu`` is the velocity the model acts on (relative to the
water when there is a current); ``tau = [tau_u, tau_v = 0, tau_r]``.

Expanding M nu_dot + C(nu) nu + D nu = tau with (4)-(6):

    m u_dot                      = tau_u + m (xg r + v) r - d11 u
    m v_dot + m xg r_dot         = -m u r - d22 v
    m xg v_dot + Iz r_dot        = tau_r - m xg u r - d33 r

The extended model (:class:`ExtendedParams`, Fossen's 3-DOF form with added mass and
quadratic damping) has M = [[m11, 0, 0], [0, m22, m26], [0, m26, m66]],
C(nu) nu = [-(m22 v + m26 r) r, m11 u r, (m22 - m11) u v + m26 u r] and
D(nu) nu = [(d11 + d11q |u|) u, (d22 + d22q |v|) v, (d33 + d33q |r|) r]:

    m11 u_dot                    = tau_u + (m22 v + m26 r) r - d11 u - d11q |u| u
    m22 v_dot + m26 r_dot        = -m11 u r - d22 v - d22q |v| v
    m26 v_dot + m66 r_dot        = tau_r - (m22 - m11) u v - m26 u r - d33 r - d33q |r| r

With m11 = m22 = m, m26 = m xg, m66 = Iz and no quadratic damping it is the paper's model.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from .._jit import jitable
from ..choices import EXTENDED_PARAM_NAMES, PARAM_NAMES, THRUST_UNITS
from ..errors import ConfigError, InputError
from . import thruster_curves


def _full_scale(full_scale) -> float:
    """The full scale of ``counts`` commands, checked: a finite number > 0."""
    if full_scale is None or not (math.isfinite(float(full_scale)) and float(full_scale) > 0):
        raise ConfigError(f"thrust commands in counts need a full scale > 0 (--thrust-range), not {full_scale}")
    return float(full_scale)


def require_finite(obj, names, kind: str) -> None:
    """Every field in ``names`` of ``obj`` is a finite number (not a bool), else ConfigError.

    Parameters
    ----------
    obj : object
        Object (usually a parameter dataclass) whose attributes are checked.
    names : iterable of str
        Attribute names to check.
    kind : str
        What the fields are, for the message (e.g. ``"vessel parameter"``).

    Raises
    ------
    usvlog.errors.ConfigError
        On the first field that is a bool, not an int/float, NaN or infinite.
    """
    for f in names:
        v = getattr(obj, f)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{kind} {f} = {v!r} is not a finite number")


CATALOGUE_MAPS = thruster_curves.CATALOGUE_MAPS
"""Thruster maps built from a manufacturer's published curves (``t200``), see
:mod:`usvlog.model.thruster_curves`."""

THRUSTER_MAPS = ("identity", "linear", "quadratic") + CATALOGUE_MAPS
"""Every thruster map a vessel's ``[thrusters] map`` may name."""

THRUSTER_SIDES = ("left", "right")
"""Names of the two thrusters (port, starboard), for :meth:`Thrusters.command_to_force`."""


@dataclass(frozen=True, kw_only=True)
class VesselParams:
    """Model parameters of eq. (3), SI units, paper symbols.

    Defaults are the paper's Section IV vessel.

    Parameters
    ----------
    m : float, default 33.0
        Mass in kg, > 0.
    Iz : float, default 10.0
        Yaw moment of inertia about the body origin in kg m^2, > 0.
    d11 : float, default 5.0
        Linear surge damping in N s/m (kg/s), >= 0.
    d22 : float, default 5.0
        Linear sway damping in N s/m (kg/s), >= 0.
    d33 : float, default 5.0
        Linear yaw damping in N m s/rad (kg m^2/s), >= 0.
    xg : float, default 0.1
        Longitudinal position of the centre of gravity ahead of the body origin in m.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not a finite number, ``m`` or ``Iz`` is not positive or a damping
        coefficient is negative.
    """

    m: float = 33.0
    Iz: float = 10.0
    d11: float = 5.0
    d22: float = 5.0
    d33: float = 5.0
    xg: float = 0.1

    def __post_init__(self):
        require_finite(self, PARAM_NAMES, "vessel parameter")
        if self.m <= 0:
            raise ConfigError(f"vessel parameter m = {self.m} must be > 0")
        if self.Iz <= 0:
            raise ConfigError(f"vessel parameter Iz = {self.Iz} must be > 0")
        for f in ("d11", "d22", "d33"):
            if getattr(self, f) < 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be >= 0")

    @property
    def Iz_eff(self) -> float:
        """Iz - m xg^2: Theorem 3.1 condition 1 requires it > 0."""
        return self.Iz - self.m * self.xg**2

    def as_array(self) -> np.ndarray:
        """Parameters as a float array of shape (6,), in the order of ``PARAM_NAMES``.

        Returns
        -------
        numpy.ndarray
            ``[m (kg), Iz (kg m^2), d11 (kg/s), d22 (kg/s), d33 (kg m^2/s), xg (m)]``.
        """
        return np.array([getattr(self, f) for f in PARAM_NAMES], dtype=float)

    def to_dict(self) -> dict[str, float]:
        """Parameters by paper symbol (``m, Iz, d11, d22, d33, xg``) as Python floats, SI units."""
        return {f: float(getattr(self, f)) for f in PARAM_NAMES}


@dataclass(frozen=True, kw_only=True)
class ExtendedParams:
    """Parameters of the extended 3-DOF model (see the module docstring), SI units.

    Inertia terms are rigid body plus added mass, about the body origin. The paper's
    model is the special case m11 = m22 = m, m26 = m xg, m66 = Iz, d11q = d22q = d33q = 0
    (:meth:`from_paper`).

    Parameters
    ----------
    m11 : float
        Surge inertia m - X_udot in kg, > 0.
    m22 : float
        Sway inertia m - Y_vdot in kg, > 0.
    m26 : float
        Sway-yaw coupling m xg - Y_rdot (= m xg - N_vdot) in kg m.
    m66 : float
        Yaw inertia Iz - N_rdot in kg m^2, > 0; m22 m66 - m26^2 must be > 0.
    d11, d22 : float
        Linear surge and sway damping in kg/s, >= 0.
    d33 : float
        Linear yaw damping in kg m^2/s, >= 0.
    d11q, d22q : float, default 0.0
        Quadratic surge and sway damping in kg/m, >= 0 (force d11q |u| u).
    d33q : float, default 0.0
        Quadratic yaw damping in kg m^2, >= 0 (moment d33q |r| r).
    map_u_mps, map_v_mps, map_r_radps : float, default 1.0, 0.1, 0.2
        Typical |u| (m/s), |v| (m/s) and |r| (rad/s) at which :meth:`paper_terms` folds the
        quadratic damping into the paper's linear terms, >= 0.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not a finite number, an inertia is not positive, the sway-yaw
        block is not positive definite or a damping coefficient is negative.
    """

    m11: float
    m22: float
    m26: float
    m66: float
    d11: float
    d22: float
    d33: float
    d11q: float = 0.0
    d22q: float = 0.0
    d33q: float = 0.0
    map_u_mps: float = 1.0
    map_v_mps: float = 0.1
    map_r_radps: float = 0.2

    def __post_init__(self):
        require_finite(self, EXTENDED_PARAM_NAMES + ("map_u_mps", "map_v_mps", "map_r_radps"),
                       "vessel parameter")
        for f in ("m11", "m22", "m66"):
            if getattr(self, f) <= 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be > 0")
        for f in ("d11", "d22", "d33", "d11q", "d22q", "d33q", "map_u_mps", "map_v_mps", "map_r_radps"):
            if getattr(self, f) < 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be >= 0")
        if self.m22 * self.m66 - self.m26 ** 2 <= 0:
            raise ConfigError(f"vessel parameters m22 m66 - m26^2 = {self.m22 * self.m66 - self.m26 ** 2:.6g} "
                              "must be > 0 (a positive definite inertia)")

    @classmethod
    def from_paper(cls, p: VesselParams) -> ExtendedParams:
        """The paper's model written in the extended form (exactly the same dynamics).

        Parameters
        ----------
        p : VesselParams

        Returns
        -------
        ExtendedParams
            m11 = m22 = m, m26 = m xg, m66 = Iz, the paper's linear damping, no quadratic.
        """
        return cls(m11=p.m, m22=p.m, m26=p.m * p.xg, m66=p.Iz, d11=p.d11, d22=p.d22, d33=p.d33)

    def paper_terms(self) -> VesselParams:
        """The paper's model nearest to this one, for the paper's controller and estimator.

        m = m11 (surge inertia), Iz = m66, xg = m26 / m11, and each damping linearised
        at its typical speed: d11 + d11q map_u_mps, d22 + d22q map_v_mps,
        d33 + d33q map_r_radps. The sway inertia m22 and the Munk moment (m22 - m11) u v
        have no place in the paper's model and are dropped.

        Returns
        -------
        VesselParams
        """
        return VesselParams(m=self.m11, Iz=self.m66, xg=self.m26 / self.m11,
                            d11=self.d11 + self.d11q * self.map_u_mps,
                            d22=self.d22 + self.d22q * self.map_v_mps,
                            d33=self.d33 + self.d33q * self.map_r_radps)

    def as_array(self) -> np.ndarray:
        """Parameters as a float array of shape (10,), in the order of ``EXTENDED_PARAM_NAMES``.

        Returns
        -------
        numpy.ndarray
            ``[m11, m22, m26, m66, d11, d11q, d22, d22q, d33, d33q]`` (SI units).
        """
        return np.array([getattr(self, f) for f in EXTENDED_PARAM_NAMES], dtype=float)

    def to_dict(self) -> dict[str, float]:
        """Every field (the parameters and the typical speeds) as Python floats, SI units."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True, kw_only=True)
class Thrusters:
    """Twin-thruster geometry and the map from recorded command to force (N).

    ``map``: ``identity`` (commands already newtons), ``linear`` (F = forward_n c for
    c >= 0, reverse_n c below) or ``quadratic`` (F = forward_n c|c| / reverse_n c|c|),
    with c the normalized command in [-1, 1]. PWM commands are first normalized with
    ``pwm_neutral_us`` and ``pwm_span_us`` (full command at neutral +- span).
    ``forward_n``/``reverse_n`` are also the force limits used for saturation.

    A catalogue map (``t200``, :data:`CATALOGUE_MAPS`) is a manufacturer's published curve
    (:mod:`usvlog.model.thruster_curves`) at the supply voltage ``supply_v``: the command
    c is read as the pulse width 1500 + 400 c us of that curve (with the default PWM
    settings, a logged pulse width is used as it is), with its deadband about 1500 us,
    its forward/reverse asymmetry and its non-linear shape; ``forward_n``/``reverse_n``
    are then the curve's own maxima at that voltage (any values given are replaced).

    A reversed channel (``reversed_left``/``reversed_right``: ESC or propeller reversed)
    has the sign of its command about neutral flipped before the map, so that 1100 us
    drives it forward; the methods converting commands then need to know which thruster
    a command is for (``side``).

    Parameters
    ----------
    arm_m : float, default 0.3
        Lateral distance of each thruster from the centre line in m, > 0.
    map : {"identity", "linear", "quadratic", "t200"}, default "identity"
        Command-to-force map (see above).
    forward_n : float, default 20.0
        Largest forward force of one thruster in N (full positive command), > 0; for a
        catalogue map, the map's maximum at ``supply_v``.
    reverse_n : float, default 12.0
        Largest reverse force of one thruster in N, as a positive number, > 0; for a
        catalogue map, the map's maximum reverse force at ``supply_v``.
    pwm_neutral_us : float, default 1500.0
        PWM pulse width giving zero thrust, in microseconds.
    pwm_span_us : float, default 400.0
        PWM offset from neutral giving full thrust, in microseconds, > 0.
    known : bool, default True
        False when the map is only a guess (identification reports it).
    lag_s : float, default 0.0
        Time constant in s of a first-order lag between the command and the force
        (T dF/dt = F_cmd - F; the simulator applies it, 0 = none), >= 0.
    scale : {"known", "command"}, default "known"
        ``command`` when the forces are in command units (an identification without a
        known thrust scale: ``forward_n = 1`` is the full forward command, and the model
        parameters are per unit of its force); ``known``: newtons.
    supply_v : float or None, default None
        Supply voltage of the thrusters in V; required by a catalogue map and within its
        published range (T200: 10..20 V), unused by the other maps.
    reversed_left, reversed_right : bool, default False
        The port / starboard channel is reversed (its command's sign about neutral is
        flipped before the map).

    Raises
    ------
    usvlog.errors.ConfigError
        If ``map`` is unknown, a length, force or span is not positive, a catalogue map
        has no ``supply_v`` or one outside its published range, or a reversed flag is not
        a bool.
    """

    arm_m: float = 0.3
    map: str = "identity"
    forward_n: float = 20.0
    reverse_n: float = 12.0
    pwm_neutral_us: float = 1500.0
    pwm_span_us: float = 400.0
    known: bool = True  # False when the map is only a guess (reported by identification)
    lag_s: float = 0.0  # first-order force lag of the thrusters, s (simulated plant)
    scale: str = "known"  # "command": forces (and the model) in command units, thrust gain unknown
    supply_v: float | None = None  # supply voltage, V (catalogue maps)
    reversed_left: bool = False    # port channel reversed (ESC or propeller)
    reversed_right: bool = False   # starboard channel reversed

    def __post_init__(self):
        if self.scale not in ("known", "command"):
            raise ConfigError(f"thruster scale {self.scale!r} is not known or command")
        if not (self.lag_s >= 0 and math.isfinite(self.lag_s)):
            raise ConfigError(f"thruster lag_s = {self.lag_s} must be a finite number >= 0")
        if self.map in thruster_curves.UNAVAILABLE:
            raise ConfigError(f"thruster map {self.map!r}: {thruster_curves.UNAVAILABLE[self.map]}")
        if self.map not in THRUSTER_MAPS:
            raise ConfigError(f"thruster map {self.map!r} is not one of {', '.join(THRUSTER_MAPS)}")
        for f in ("reversed_left", "reversed_right"):
            if not isinstance(getattr(self, f), bool):
                raise ConfigError(f"thruster {f} = {getattr(self, f)!r} must be true or false")
        if self.supply_v is not None:
            require_finite(self, ("supply_v",), "thruster")
            if self.supply_v <= 0:
                raise ConfigError(f"thruster supply_v = {self.supply_v} must be > 0 (V)")
        if self.map in CATALOGUE_MAPS:
            _pwm, force = thruster_curves.curve(self.map, self.supply_v)  # type: ignore[arg-type]  # None: ConfigError
            object.__setattr__(self, "forward_n", float(force[-1]))
            object.__setattr__(self, "reverse_n", float(-force[0]))
        if not (self.arm_m > 0 and math.isfinite(self.arm_m)):
            raise ConfigError(f"thruster arm_m = {self.arm_m} must be a finite number > 0")
        if not (self.forward_n > 0 and self.reverse_n > 0):
            raise ConfigError("thruster forward_n and reverse_n must be > 0")
        if not (self.pwm_span_us > 0):
            raise ConfigError(f"thruster pwm_span_us = {self.pwm_span_us} must be > 0")

    # -- command <-> force -------------------------------------------------------
    @property
    def catalogue(self) -> bool:
        """True when ``map`` is a manufacturer's published curve (:data:`CATALOGUE_MAPS`)."""
        return self.map in CATALOGUE_MAPS

    def curve(self) -> tuple[np.ndarray, np.ndarray]:
        """The catalogue map's force curve at ``supply_v`` (one thruster).

        Returns
        -------
        pwm_us : numpy.ndarray
            Pulse widths in us of the curve's own frame (neutral 1500, full 1100/1900).
        force_n : numpy.ndarray
            Force in N at each pulse width, non-decreasing.

        Raises
        ------
        usvlog.errors.ConfigError
            If ``map`` is not a catalogue map.
        """
        if not self.catalogue:
            raise ConfigError(f"thruster map {self.map!r} is not a catalogue map ({', '.join(CATALOGUE_MAPS)})")
        return thruster_curves.curve(self.map, self.supply_v)  # type: ignore[arg-type]  # None: ConfigError

    def direction(self, side: str | None) -> float:
        """+1, or -1 for a reversed channel: the factor on a command's sign about neutral.

        Parameters
        ----------
        side : {"left", "right"} or None
            The thruster the command is for; None is accepted only when neither channel
            is reversed.

        Returns
        -------
        float
            -1.0 when ``side``'s channel is reversed, else 1.0.

        Raises
        ------
        usvlog.errors.ConfigError
            If ``side`` is not left/right/None, or is None while a channel is reversed.
        """
        if side is None:
            if self.reversed_left or self.reversed_right:
                rev = " and ".join(f"reversed_{k} = true" for k in THRUSTER_SIDES if getattr(self, f"reversed_{k}"))
                raise ConfigError(f"thrusters have {rev}: say which thruster a command is for (side='left' or "
                                  "'right') to convert it")
            return 1.0
        if side not in THRUSTER_SIDES:
            raise ConfigError(f"thruster side {side!r} is not left or right")
        return -1.0 if getattr(self, f"reversed_{side}") else 1.0

    def normalize(self, command, unit: str, full_scale: float | None = None, side: str | None = None):
        """Recorded command -> normalized command in [-1, 1] (pwm_us, normalized or counts).

        Parameters
        ----------
        command : float or array_like
            Thruster command(s) in ``unit``.
        unit : {"normalized", "pwm_us", "counts"}
            Unit of ``command``: already normalized, a PWM pulse width in microseconds, or
            integer counts (full command at +- ``full_scale``).
        full_scale : float, optional
            Counts of a full command (e.g. 255), > 0; required for ``counts``.
        side : {"left", "right"}, optional
            The thruster the command is for: a reversed channel's command has its sign
            flipped (1100 us then reads as full forward). Required when a channel is
            reversed.

        Returns
        -------
        numpy.ndarray
            Normalized command as the thruster sees it, clipped to [-1, 1], of the input's
            shape.

        Raises
        ------
        usvlog.errors.ConfigError
            For any other unit (``newton`` commands have no normalized form), ``counts``
            without a positive ``full_scale``, or no ``side`` while a channel is reversed.
        """
        c = np.asarray(command, dtype=float)
        if unit == "normalized":
            n = c
        elif unit == "pwm_us":
            n = (c - self.pwm_neutral_us) / self.pwm_span_us
        elif unit == "counts":
            n = c / _full_scale(full_scale)
        else:
            raise ConfigError(f"thrust unit {unit!r} cannot be normalized")
        return np.clip(self.direction(side) * n, -1.0, 1.0)

    def command_to_force(self, command, unit: str, full_scale: float | None = None, side: str | None = None):
        """Recorded thruster command in ``unit`` -> force in newtons.

        Parameters
        ----------
        command : float or array_like
            Thruster command(s) as recorded.
        unit : {"newton", "normalized", "pwm_us", "counts"}
            Unit of ``command``: N, normalized [-1, 1], PWM pulse width in microseconds, or
            integer counts (full command at +- ``full_scale``).
        full_scale : float, optional
            Counts of a full command, > 0; required for ``counts``.
        side : {"left", "right"}, optional
            The thruster the command is for (a reversed channel's command is flipped);
            required for a command that is not in newtons when a channel is reversed.

        Returns
        -------
        numpy.ndarray
            Force of one thruster in N, of the input's shape. Newton commands are returned
            as given (copied, not saturated, never flipped); the others go through the
            thruster map and so stay within [-reverse_n, forward_n].

        Raises
        ------
        usvlog.errors.ConfigError
            If ``unit`` is unknown, if a normalized or PWM command meets the ``identity``
            map, or if ``side`` is missing while a channel is reversed.
        """
        if unit not in THRUST_UNITS:
            raise ConfigError(f"thrust unit {unit!r} is not one of {', '.join(THRUST_UNITS)}")
        c = np.asarray(command, dtype=float)
        if unit == "newton":
            return c.copy()
        c = self.normalize(c, unit, full_scale, side)
        if self.map == "identity":
            raise ConfigError(
                f"thrust commands in {unit} need a thruster map (linear, quadratic or a catalogue map), not identity")
        if self.catalogue:
            pwm, f = self.curve()
            pwm_c = thruster_curves.CURVE_NEUTRAL_US + thruster_curves.CURVE_SPAN_US * c
            return np.asarray(thruster_curves.force_from_pwm(pwm_c, pwm, f), dtype=float)
        shape = c if self.map == "linear" else c * np.abs(c)
        return np.where(c >= 0, self.forward_n * shape, self.reverse_n * shape)

    def force_to_command(self, force, unit: str, full_scale: float | None = None, side: str | None = None):
        """Force in newtons -> command in ``unit`` (saturated to the thruster limits).

        Inverse of :meth:`command_to_force` within the limits. For a catalogue map, zero
        force gives the neutral command (the middle of the deadband) and a non-zero force
        the command at the deadband's edge or beyond.

        Parameters
        ----------
        force : float or array_like
            Force of one thruster in N.
        unit : {"newton", "normalized", "pwm_us", "counts"}
            Unit of the command to produce.
        full_scale : float, optional
            Counts of a full command, > 0; required for ``counts`` (the result is not
            rounded to whole counts).
        side : {"left", "right"}, optional
            The thruster the command is for (a reversed channel gets the flipped command);
            required for a command that is not in newtons when a channel is reversed.

        Returns
        -------
        numpy.ndarray
            Command of the input's shape: N (saturated), normalized [-1, 1], or PWM pulse
            width in microseconds.

        Raises
        ------
        usvlog.errors.ConfigError
            If ``unit`` is unknown, if a normalized or PWM command is asked of the
            ``identity`` map, or if ``side`` is missing while a channel is reversed.
        """
        f = self.saturate(force)
        if unit == "newton":
            return f
        if unit not in THRUST_UNITS:
            raise ConfigError(f"thrust unit {unit!r} is not one of {', '.join(THRUST_UNITS)}")
        if self.map == "identity":
            raise ConfigError(
                f"thrust commands in {unit} need a thruster map (linear, quadratic or a catalogue map), not identity")
        if self.catalogue:
            pwm, fc = self.curve()
            c = (thruster_curves.pwm_from_force(f, pwm, fc) - thruster_curves.CURVE_NEUTRAL_US) \
                / thruster_curves.CURVE_SPAN_US
        else:
            x = f / np.where(f >= 0, self.forward_n, self.reverse_n)
            c = x if self.map == "linear" else np.sign(x) * np.sqrt(np.abs(x))
        c = self.direction(side) * np.asarray(c, dtype=float)
        if unit == "normalized":
            return c
        if unit == "pwm_us":
            return self.pwm_neutral_us + self.pwm_span_us * c
        return _full_scale(full_scale) * c

    def saturate(self, force):
        """Clip force(s) of one thruster to [-reverse_n, forward_n] N.

        Parameters
        ----------
        force : float or array_like
            Force in N.

        Returns
        -------
        numpy.ndarray
            Saturated force in N, float, of the input's shape.
        """
        return np.clip(np.asarray(force, dtype=float), -self.reverse_n, self.forward_n)

    # -- geometry ----------------------------------------------------------------
    def forces_from_commands(self, left, right, units) -> tuple[np.ndarray, np.ndarray]:
        """Both thrusters' forces from commands whose unit may change from record to record.

        Parameters
        ----------
        left, right : array_like
            Port and starboard commands, one per record.
        units : array_like of str
            Each record's unit (:data:`THRUST_UNITS`).

        Returns
        -------
        f_left, f_right : numpy.ndarray
            Forces in N (:meth:`command_to_force` per unit, each channel's reversal
            applied).

        Raises
        ------
        usvlog.errors.ConfigError
            A unit this thruster map cannot turn into newtons.
        """
        left, right, units = np.asarray(left, float), np.asarray(right, float), np.asarray(units)
        fl, fr = np.full(len(left), np.nan), np.full(len(right), np.nan)
        for unit in np.unique(units):
            k = units == unit
            fl[k] = self.command_to_force(left[k], str(unit), side="left")
            fr[k] = self.command_to_force(right[k], str(unit), side="right")
        return fl, fr

    def tau_from_forces(self, f_left, f_right):
        """(tau_u, tau_r): port thruster pushing harder gives positive (starboard) r.

        Parameters
        ----------
        f_left, f_right : float or array_like
            Port and starboard thruster forces in N.

        Returns
        -------
        tau_u : numpy.ndarray
            Surge force f_left + f_right in N.
        tau_r : numpy.ndarray
            Yaw moment arm_m (f_left - f_right) in N m.
        """
        f_left, f_right = np.asarray(f_left, float), np.asarray(f_right, float)
        return f_left + f_right, self.arm_m * (f_left - f_right)

    def forces_from_tau(self, tau_u, tau_r):
        """Inverse of :meth:`tau_from_forces` (no saturation).

        Parameters
        ----------
        tau_u : float or array_like
            Surge force in N.
        tau_r : float or array_like
            Yaw moment in N m.

        Returns
        -------
        f_left, f_right : numpy.ndarray
            Port and starboard thruster forces in N (may exceed the thruster limits).
        """
        tau_u, tau_r = np.asarray(tau_u, float), np.asarray(tau_r, float)
        d = tau_r / self.arm_m
        return 0.5 * (tau_u + d), 0.5 * (tau_u - d)


@dataclass(frozen=True, kw_only=True)
class Vessel:
    """A vessel: its name, model parameters and thrusters, as read from a vessel TOML.

    Parameters
    ----------
    name : str, default "paper-section-iv"
        Name stored in logs and reports.
    params : VesselParams, default VesselParams()
        Model parameters of eq. (3) (the paper's Section IV vessel by default). For a vessel
        of the extended structure: the paper terms of ``extended``
        (:meth:`ExtendedParams.paper_terms`), which the paper's controller and the
        estimator use.
    thrusters : Thrusters, default Thrusters()
        Thruster geometry and command-to-force map.
    extended : ExtendedParams or None, default None
        The extended model, when the vessel has that structure; the simulated plant
        then follows it (see :func:`extended_vessel`).
    heading_offset_deg : float or None, default None
        Heading sensor mounting offset, deg in [-360, 360], measured minus true (the
        estimator fuses the measured heading minus it); ``[sensors] heading_offset_deg``
        in the vessel TOML. None: not stated.

    See Also
    --------
    vessel_from_toml, vessel_from_dict, default_vessel
    """

    name: str = "paper-section-iv"
    params: VesselParams = field(default_factory=VesselParams)
    thrusters: Thrusters = field(default_factory=Thrusters)
    extended: ExtendedParams | None = None
    heading_offset_deg: float | None = None

    def __post_init__(self):
        h = self.heading_offset_deg
        if h is not None and not (math.isfinite(h) and -360.0 <= h <= 360.0):
            raise ConfigError(f"[sensors] heading_offset_deg = {h} must be an angle in [-360, 360] deg")

    @property
    def structure(self) -> str:
        """``"extended"`` when the vessel has an extended model, else ``"paper"``."""
        return "paper" if self.extended is None else "extended"

    def plant_params(self) -> ExtendedParams:
        """The model the simulated plant follows, in the extended form.

        Returns
        -------
        ExtendedParams
            ``extended``, or the paper's parameters written in the extended form.
        """
        return self.extended if self.extended is not None else ExtendedParams.from_paper(self.params)

    def to_toml(self) -> str:
        """The vessel as a TOML document that :func:`vessel_from_toml` reads back exactly.

        Returns
        -------
        str
            ``name``, a ``[model]`` table (paper symbols, SI units) or, for the extended
            structure, ``structure = "extended"`` and an ``[extended]`` table, and a
            ``[thrusters]`` table; floats are written with ``repr`` (no rounding),
            infinities as ``inf``. Thruster fields at their defaults (``lag_s``,
            ``scale``, ``supply_v``, the reversed flags) are left out, and so are a
            catalogue map's ``forward_n``/``reverse_n`` (written as a comment: the map
            sets them from ``supply_v``).
        """
        p, t = self.params, self.thrusters
        lines = [f'name = "{self.name}"']
        if self.extended is None:
            lines += ["", "[model]"] + [f"{k} = {_toml_float(v)}" for k, v in p.to_dict().items()]
        else:
            lines += ['structure = "extended"', "", "[extended]"]
            lines += [f"{k} = {_toml_float(v)}" for k, v in self.extended.to_dict().items()]
        lines += ["", "[thrusters]"]
        for f in fields(Thrusters):
            v = getattr(t, f.name)
            if _thruster_default(f.name, v):
                continue  # the defaults: files of vessels without them stay as they were
            if t.catalogue and f.name in ("forward_n", "reverse_n"):
                lines.append(f"# {f.name} = {_toml_float(v)}  (the {t.map} map's own maximum at supply_v)")
                continue
            if isinstance(v, bool):
                lines.append(f"{f.name} = {'true' if v else 'false'}")
            elif isinstance(v, str):
                lines.append(f'{f.name} = "{v}"')
            else:
                lines.append(f"{f.name} = {_toml_float(v)}")
        if self.heading_offset_deg is not None:
            lines += ["", "[sensors]", f"heading_offset_deg = {_toml_float(self.heading_offset_deg)}"]
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, str]:
        """Flat string map (MCAP metadata record).

        Returns
        -------
        dict of str to str
            ``name``, ``model.<symbol>`` (the paper terms), ``extended.<field>`` (extended
            structure only) and ``thrusters.<field>`` entries (``lag_s``, ``scale``,
            ``supply_v`` and the reversed flags only when not the default);
            read back by :meth:`from_dict`.
        """
        d = {"name": self.name}
        d.update({f"model.{k}": repr(v) for k, v in self.params.to_dict().items()})
        if self.extended is not None:
            d.update({f"extended.{k}": repr(v) for k, v in self.extended.to_dict().items()})
        d.update({f"thrusters.{k}": str(v) for k, v in asdict(self.thrusters).items()
                  if not _thruster_default(k, v)})
        if self.heading_offset_deg is not None:
            d["sensors.heading_offset_deg"] = repr(self.heading_offset_deg)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, str]) -> Vessel:
        """Vessel from the flat string map written by :meth:`to_dict`.

        Parameters
        ----------
        d : mapping of str to str
            ``name`` (default ``"vessel"``), ``model.<symbol>`` and ``thrusters.<field>``
            entries; missing ones take the defaults of :class:`VesselParams` and
            :class:`Thrusters`.

        Returns
        -------
        Vessel

        Raises
        ------
        usvlog.errors.ConfigError
            If a value is out of range.
        ValueError
            If a numeric entry is not a number.
        """
        model = {k.split(".", 1)[1]: float(v) for k, v in d.items() if k.startswith("model.")}
        thr: dict = {}
        for f in fields(Thrusters):
            key = f"thrusters.{f.name}"
            if key in d:
                v = d[key]
                thr[f.name] = v if f.type == "str" else (v == "True") if f.type == "bool" else float(v)
        ext = {k.split(".", 1)[1]: float(v) for k, v in d.items() if k.startswith("extended.")}
        off = float(d["sensors.heading_offset_deg"]) if "sensors.heading_offset_deg" in d else None
        if ext:
            return replace(extended_vessel(d.get("name", "vessel"), ExtendedParams(**ext), Thrusters(**thr)),
                           heading_offset_deg=off)
        return cls(name=d.get("name", "vessel"), params=VesselParams(**model), thrusters=Thrusters(**thr),
                   heading_offset_deg=off)

    def with_params(self, **changes) -> Vessel:
        """A copy with some model parameters replaced.

        Parameters
        ----------
        **changes : float
            New values by paper symbol (``m``, ``Iz``, ``d11``, ``d22``, ``d33``, ``xg``),
            SI units as in :class:`VesselParams`.

        Returns
        -------
        Vessel
            The same name and thrusters with the new parameters (checked again). An
            extended model is dropped: the copy is a vessel of the paper's structure.
        """
        return replace(self, params=replace(self.params, **changes), extended=None)


def extended_vessel(name: str, ext: ExtendedParams, thrusters: Thrusters | None = None) -> Vessel:
    """A vessel of the extended structure, its paper terms derived from the extended model.

    Parameters
    ----------
    name : str
        Vessel name.
    ext : ExtendedParams
        The extended model (the simulated plant follows it).
    thrusters : Thrusters, optional
        Default ``Thrusters()``.

    Returns
    -------
    Vessel
        ``params`` = :meth:`ExtendedParams.paper_terms` (what the paper's controller and
        the estimator use), ``extended`` = ``ext``.
    """
    return Vessel(name=str(name), params=ext.paper_terms(), thrusters=thrusters or Thrusters(), extended=ext)


_THRUSTER_DEFAULTS = (("lag_s", 0.0), ("scale", "known"), ("supply_v", None), ("reversed_left", False),
                      ("reversed_right", False))


def _thruster_default(name: str, value) -> bool:
    """A thruster field a vessel file or metadata record leaves out when it has this value."""
    for k, d in _THRUSTER_DEFAULTS:
        if name == k:
            return value is d if (d is None or isinstance(d, bool)) else value == d
    return False


def _toml_float(v: float) -> str:
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(float(v))


def vessel_from_toml(text: str, source: str = "<vessel>") -> Vessel:
    """Parse a vessel TOML document (see README) into a :class:`Vessel`.

    Parameters
    ----------
    text : str
        The TOML document: ``name``, ``[model]`` (paper symbols, SI units) or, for the
        extended structure, ``[extended]`` (fields of :class:`ExtendedParams`; optionally
        ``structure = "extended"``), and ``[thrusters]`` (fields of :class:`Thrusters`);
        missing keys take the defaults.
    source : str, default "<vessel>"
        Name of the document (usually its path), for error messages.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.ConfigError
        If the text is not valid TOML, has an unknown key or a value out of range.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{source}: not valid TOML: {err}") from err
    return vessel_from_dict(doc, source)


def vessel_from_dict(doc: dict, source: str = "<vessel>") -> Vessel:
    """A parsed vessel document ({name, model: {...}, thrusters: {...}}) -> :class:`Vessel`.

    Parameters
    ----------
    doc : dict
        The parsed document; see :func:`vessel_from_toml`.
    source : str, default "<vessel>"
        Name of the document, for error messages.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown key or a value that is not a number or out of range, or a
        structure that does not match the tables given.
    """
    structure = doc.get("structure", "extended" if "extended" in doc else "paper")
    if structure not in ("paper", "extended"):
        raise ConfigError(f"{source}: structure {structure!r} is not paper or extended")
    offset = _heading_offset_from_dict(doc.get("sensors", {}), source)
    if structure == "extended":
        return replace(_extended_from_dict(doc, source), heading_offset_deg=offset)
    if "extended" in doc:
        raise ConfigError(f"{source}: an [extended] table needs structure = \"extended\"")
    model = doc.get("model", {})
    known_m = set(PARAM_NAMES)
    for k in model:
        if k not in known_m:
            raise ConfigError(f"{source}: [model] has unknown key {k!r} (expected {', '.join(PARAM_NAMES)})")
    thrusters = _thrusters_from_dict(doc.get("thrusters", {}), source)
    try:
        params = VesselParams(**{k: float(v) for k, v in model.items()})
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    return Vessel(name=str(doc.get("name", "vessel")), params=params, thrusters=thrusters, heading_offset_deg=offset)


def _heading_offset_from_dict(sensors: dict, source: str) -> float | None:
    """``[sensors] heading_offset_deg`` (deg, in [-360, 360]) or None; no other key is known."""
    if not isinstance(sensors, dict):
        raise ConfigError(f"{source}: sensors must be a table ([sensors])")
    for k in sensors:
        if k != "heading_offset_deg":
            raise ConfigError(f"{source}: [sensors] has unknown key {k!r} (expected heading_offset_deg)")
    v = sensors.get("heading_offset_deg")
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and -360.0 <= v <= 360.0):
        raise ConfigError(f"{source}: [sensors] heading_offset_deg = {v!r} must be an angle in [-360, 360] deg")
    return float(v)


def _thrusters_from_dict(thr: dict, source: str) -> Thrusters:
    known_t = {f.name for f in fields(Thrusters)}
    for k in thr:
        if k not in known_t:
            raise ConfigError(f"{source}: [thrusters] has unknown key {k!r}")
    try:
        tvals: dict[str, Any] = {k: (v if isinstance(v, (str, bool)) else float(v)) for k, v in thr.items()}
        t = Thrusters(**tvals)
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    if t.catalogue:   # a catalogue map sets its own limits: a file may omit them, not contradict them
        for k in ("forward_n", "reverse_n"):
            if k in tvals and not (isinstance(tvals[k], float) and math.isclose(tvals[k], getattr(t, k), rel_tol=1e-9)):
                raise ConfigError(f"{source}: [thrusters] {k} = {tvals[k]!r} N contradicts the {t.map} map's "
                                  f"{getattr(t, k):.4g} N at supply_v = {t.supply_v:g} V (leave {k} out)")
    return t


def _extended_from_dict(doc: dict, source: str) -> Vessel:
    """A vessel of the extended structure from its parsed document (``[extended]``, no ``[model]``)."""
    if "model" in doc:
        raise ConfigError(f"{source}: an extended vessel takes [extended], not [model] (its paper terms are "
                          "derived from the extended model)")
    ext = doc.get("extended")
    if not isinstance(ext, dict):
        raise ConfigError(f"{source}: structure = \"extended\" needs an [extended] table")
    known = {f.name for f in fields(ExtendedParams)}
    for k in ext:
        if k not in known:
            raise ConfigError(f"{source}: [extended] has unknown key {k!r} (expected {', '.join(sorted(known))})")
    for k in ("m11", "m22", "m26", "m66", "d11", "d22", "d33"):
        if k not in ext:
            raise ConfigError(f"{source}: [extended] lacks {k}")
    try:
        params = ExtendedParams(**{k: float(v) for k, v in ext.items()})
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    return extended_vessel(str(doc.get("name", "vessel")), params, _thrusters_from_dict(doc.get("thrusters", {}),
                                                                                        source))


def default_vessel() -> Vessel:
    """The paper's Section IV vessel: m = 33 kg, Iz = 10 kg m^2, d = 5, xg = 0.1 m.

    Returns
    -------
    Vessel
        ``Vessel()``: the default :class:`VesselParams` and :class:`Thrusters`
        (identity map, 0.3 m arm, 20 N forward / 12 N reverse).
    """
    return Vessel()


# ---------------------------------------------------------------------------
# Dynamics, eq. (3); vectorised over leading axes
# ---------------------------------------------------------------------------

def mass_matrix(p: VesselParams) -> np.ndarray:
    """M of eq. (4).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Rigid-body mass matrix, shape (3, 3), in kg, kg m and kg m^2.
    """
    return np.array([[p.m, 0.0, 0.0], [0.0, p.m, p.m * p.xg], [0.0, p.m * p.xg, p.Iz]])


def coriolis_matrix(nu, p: VesselParams) -> np.ndarray:
    """C(nu) of eq. (5), shape (..., 3, 3).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Coriolis-centripetal matrix of shape ``nu.shape[:-1] + (3, 3)``.
    """
    nu = np.asarray(nu, float)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    z = np.zeros_like(u)
    a = p.m * (p.xg * r + v)
    b = p.m * u
    return np.stack([np.stack([z, z, -a], -1), np.stack([z, z, b], -1), np.stack([a, -b, z], -1)], -2)


def damping_matrix(p: VesselParams) -> np.ndarray:
    """D of eq. (6).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Linear damping matrix diag(d11, d22, d33), shape (3, 3).
    """
    return np.diag([p.d11, p.d22, p.d33])


@jitable
def nu_dot_terms(u, v, r, tau_u, tau_r, m, Iz, d11, d22, d33, xg):
    """(u_dot, v_dot, r_dot) of eq. (3) in closed form.

    Plain arithmetic, so it serves scalars (the simulators' inner loops) and arrays alike,
    in Python and inside numba-compiled loops (:func:`usvlog._jit.jitable`).
    """
    f1 = tau_u + m * (xg * r + v) * r - d11 * u
    f2 = -m * u * r - d22 * v
    f3 = tau_r - m * xg * u * r - d33 * r
    det = m * Iz - (m * xg) * (m * xg)
    return f1 / m, (Iz * f2 - m * xg * f3) / det, (m * f3 - m * xg * f2) / det


@jitable
def nu_dot_ext_terms(u, v, r, tau_u, tau_r, m11, m22, m26, m66, d11, d11q, d22, d22q, d33, d33q):
    """(u_dot, v_dot, r_dot) of the extended model (module docstring) in closed form.

    Plain arithmetic like :func:`nu_dot_terms` (scalars and arrays, Python and numba);
    parameters in ``EXTENDED_PARAM_NAMES`` order, SI units.
    """
    f1 = tau_u + (m22 * v + m26 * r) * r - d11 * u - d11q * abs(u) * u
    f2 = -m11 * u * r - d22 * v - d22q * abs(v) * v
    f3 = tau_r - (m22 - m11) * u * v - m26 * u * r - d33 * r - d33q * abs(r) * r
    det = m22 * m66 - m26 * m26
    return f1 / m11, (m66 * f2 - m26 * f3) / det, (m22 * f3 - m26 * f2) / det


def nu_dot_ext(nu, tau_u, tau_r, p: ExtendedParams):
    """nu_dot of the extended model, vectorised over leading axes.

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : ExtendedParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [u_dot (m/s^2), v_dot (m/s^2), r_dot (rad/s^2)].
    """
    nu = np.asarray(nu, float)
    ud, vd, rd = nu_dot_ext_terms(nu[..., 0], nu[..., 1], nu[..., 2], tau_u, tau_r, *p.as_array())
    return np.stack(np.broadcast_arrays(ud, vd, rd), -1)


def nu_dot(nu, tau_u, tau_r, p: VesselParams):
    """nu_dot = M^-1 (tau - C(nu) nu - D nu), vectorised over leading axes.

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N, broadcast against ``nu[..., 0]``.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [u_dot (m/s^2), v_dot (m/s^2), r_dot (rad/s^2)].
    """
    nu = np.asarray(nu, float)
    ud, vd, rd = nu_dot_terms(nu[..., 0], nu[..., 1], nu[..., 2], tau_u, tau_r,
                              p.m, p.Iz, p.d11, p.d22, p.d33, p.xg)
    return np.stack(np.broadcast_arrays(ud, vd, rd), -1)


def nu_dot_jacobian_terms(u, v, r, m, Iz, d11, d22, d33, xg):
    """The nine entries of d(nu_dot)/d(nu), row-major, in closed form.

    Plain arithmetic like :func:`nu_dot_terms`, so compiled inner loops (numba) and
    arrays share it; :func:`nu_dot_jacobian` stacks it.
    """
    det = m * Iz - (m * xg) * (m * xg)
    # partials of f1, f2, f3 of nu_dot_terms w.r.t. (u, v, r)
    a1, a2, a3 = -d11 + 0.0 * u, m * r, m * v + 2.0 * m * xg * r
    b1, b2, b3 = -m * r, -d22 + 0.0 * u, -m * u
    c1, c2, c3 = -m * xg * r, 0.0 * u, -m * xg * u - d33
    return (a1 / m, a2 / m, a3 / m,
            (Iz * b1 - m * xg * c1) / det, (Iz * b2 - m * xg * c2) / det, (Iz * b3 - m * xg * c3) / det,
            (m * c1 - m * xg * b1) / det, (m * c2 - m * xg * b2) / det, (m * c3 - m * xg * b3) / det)


def nu_dot_jacobian(nu, p: VesselParams):
    """d(nu_dot)/d(nu), shape (..., 3, 3); tau enters linearly (see :func:`nu_dot_tau_matrix`).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Jacobian of shape ``nu.shape[:-1] + (3, 3)``, rows u_dot, v_dot, r_dot.
    """
    nu = np.asarray(nu, float)
    t = nu_dot_jacobian_terms(nu[..., 0], nu[..., 1], nu[..., 2],
                              p.m, p.Iz, p.d11, p.d22, p.d33, p.xg)
    t = np.broadcast_arrays(*t)
    return np.stack([np.stack(t[0:3], -1), np.stack(t[3:6], -1), np.stack(t[6:9], -1)], -2)


def nu_dot_tau_matrix(p: VesselParams) -> np.ndarray:
    """B such that nu_dot = ... + B @ [tau_u, tau_r] (the input matrix).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Shape (3, 2): columns for tau_u (N) and tau_r (N m).
    """
    det = p.m * p.Iz - (p.m * p.xg) ** 2
    return np.array([[1.0 / p.m, 0.0], [0.0, -p.m * p.xg / det], [0.0, p.m / det]])


def eta_dot(eta, nu, current_ne=(0.0, 0.0)):
    """Eq. (1) plus a current in NED: eta_dot = R(psi) nu + [c_n, c_e, 0].

    Parameters
    ----------
    eta : array_like, shape (..., 3)
        Pose [n (m), e (m), psi (rad)].
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [n_dot (m/s), e_dot (m/s), psi_dot (rad/s)].
    """
    eta, nu = np.asarray(eta, float), np.asarray(nu, float)
    psi = eta[..., 2]
    c, s = np.cos(psi), np.sin(psi)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    return np.stack([c * u - s * v + current_ne[0], s * u + c * v + current_ne[1], r], -1)


def plant_rhs(x, tau_u, tau_r, p: VesselParams, current_ne=(0.0, 0.0)):
    """State x = [n, e, psi, u, v, r] -> x_dot (eqs. (1) and (3)).

    Parameters
    ----------
    x : array_like, shape (..., 6)
        [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)]; u, v relative to the water.
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 6)
        Time derivative of ``x`` (SI units per second).
    """
    x = np.asarray(x, float)
    return np.concatenate([eta_dot(x[..., :3], x[..., 3:], current_ne),
                           nu_dot(x[..., 3:], tau_u, tau_r, p)], -1)


def plant_jacobian(x, p: VesselParams):
    """d(plant_rhs)/dx, shape (..., 6, 6) (independent of tau and of a constant current).

    Parameters
    ----------
    x : array_like, shape (..., 6)
        State [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Jacobian of shape ``x.shape[:-1] + (6, 6)``.
    """
    x = np.asarray(x, float)
    psi, u, v = x[..., 2], x[..., 3], x[..., 4]
    c, s = np.cos(psi), np.sin(psi)
    J = np.zeros(x.shape[:-1] + (6, 6))
    J[..., 0, 2] = -s * u - c * v
    J[..., 1, 2] = c * u - s * v
    J[..., 0, 3], J[..., 0, 4] = c, -s
    J[..., 1, 3], J[..., 1, 4] = s, c
    J[..., 2, 5] = 1.0
    J[..., 3:, 3:] = nu_dot_jacobian(x[..., 3:], p)
    return J


def model_residual(nu, nu_dot_meas, tau_u, tau_r, p: VesselParams):
    """M nu_dot + C(nu) nu + D nu - tau for given accelerations (shape (..., 3)).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    nu_dot_meas : array_like, shape (..., 3)
        Measured or smoothed accelerations [m/s^2, m/s^2, rad/s^2].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        Equation error [N, N, N m]; zero where the data follow the model exactly.
    """
    nu = np.asarray(nu, float)
    M, D = mass_matrix(p), damping_matrix(p)
    Cnu = np.einsum("...ij,...j->...i", coriolis_matrix(nu, p), nu)
    tau = np.stack([np.asarray(tau_u, float) + 0 * nu[..., 0], 0 * nu[..., 0],
                    np.asarray(tau_r, float) + 0 * nu[..., 0]], -1)
    return np.asarray(nu_dot_meas) @ M.T + Cnu + nu @ D.T - tau


def rk4_step(x, tau_u, tau_r, p: VesselParams, dt: float, current_ne=(0.0, 0.0)):
    """One RK4 step of the plant with thrust held over the step.

    Parameters
    ----------
    x : array_like, shape (..., 6)
        State [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams
    dt : float
        Step in s.
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 6)
        State after ``dt``.
    """
    k1 = plant_rhs(x, tau_u, tau_r, p, current_ne)
    k2 = plant_rhs(x + 0.5 * dt * k1, tau_u, tau_r, p, current_ne)
    k3 = plant_rhs(x + 0.5 * dt * k2, tau_u, tau_r, p, current_ne)
    k4 = plant_rhs(x + dt * k3, tau_u, tau_r, p, current_ne)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def euler_step(x, tau_u, tau_r, p: VesselParams, dt: float, current_ne=(0.0, 0.0)):
    """First-order step, as the paper's Section IV simulation.

    Parameters are those of :func:`rk4_step`; returns the state after ``dt`` s,
    x + dt plant_rhs(x).
    """
    return x + dt * plant_rhs(x, tau_u, tau_r, p, current_ne)


def check_finite(name: str, arr, source: str = "") -> None:
    """Raise InputError if ``arr`` holds a NaN or an infinity.

    Parameters
    ----------
    name : str
        Name of the array (a column or channel), for the message.
    arr : array_like
        Values to check; rows are along the first axis.
    source : str, default ""
        File or channel the values come from, prefixed to the message.

    Raises
    ------
    usvlog.errors.InputError
        Naming the first row (first-axis index) with a non-finite value.
    """
    a = np.asarray(arr, float)
    if not np.all(np.isfinite(a)):
        i = int(np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).any(-1))[0]) if a.ndim else 0
        raise InputError(f"{source} {name}: non-finite value at row {i}".strip())
