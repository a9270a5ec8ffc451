"""Twin thrusters: their geometry and the map from a recorded command to force and back.

:class:`Thrusters` turns commands (newtons, normalized, PWM pulse widths or counts) into
the force of each thruster through a map (identity, linear, quadratic or a manufacturer's
published curve, :mod:`usvlog.model.thruster_curves`), and the two forces into the surge
force and yaw moment of the model (port thruster pushing harder gives positive r).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..choices import THRUST_UNITS
from ..errors import ConfigError
from . import thruster_curves
from .dynamics import require_finite


def _full_scale(full_scale) -> float:
    """The full scale of ``counts`` commands, checked: a finite number > 0."""
    if full_scale is None or not (math.isfinite(float(full_scale)) and float(full_scale) > 0):
        raise ConfigError(f"thrust commands in counts need a full scale > 0 (--thrust-range), not {full_scale}")
    return float(full_scale)



CATALOGUE_MAPS = thruster_curves.CATALOGUE_MAPS
"""Thruster maps built from a manufacturer's published curves (``t200``), see
:mod:`usvlog.model.thruster_curves`."""

SHAPED_MAPS = ("linear", "quadratic", "mixed")
"""Maps given by a shape s(x) and two gains (``forward_n``, ``reverse_n``); the ones that
take a ``deadband_us``."""

THRUSTER_MAPS = ("identity",) + SHAPED_MAPS + CATALOGUE_MAPS
"""Every thruster map a vessel's ``[thrusters] map`` may name."""

THRUSTER_SIDES = ("left", "right")
"""Names of the two thrusters (port, starboard), for :meth:`Thrusters.command_to_force`."""



@dataclass(frozen=True, kw_only=True)
class Thrusters:
    """Twin-thruster geometry and the map from recorded command to force (N).

    ``map``: ``identity`` (commands already newtons), ``linear`` (F = forward_n c for
    c >= 0, reverse_n c below), ``quadratic`` (F = forward_n c|c| / reverse_n c|c|) or
    ``mixed`` (F = forward_n s(c) / reverse_n s(c) with s(c) = (1 - q) c + q c|c|, q =
    ``quadratic_share``: linear at q = 0, quadratic at q = 1), with c the normalized
    command in [-1, 1]. PWM commands are first normalized with ``pwm_neutral_us`` and
    ``pwm_span_us`` (full command at neutral +- span). ``forward_n``/``reverse_n`` are also
    the force limits used for saturation.

    These three maps may have a deadband (``deadband_us``, a half-width h about neutral,
    symmetric: an ESC gives no thrust for pulse widths within neutral +- h). With
    d = h / pwm_span_us the command is then read as x = sign(c) (|c| - d) / (1 - d)
    beyond the deadband and 0 within it, and F = forward_n s(x) / reverse_n s(x): the
    force starts at the deadband's edge and full command still gives forward_n / reverse_n.
    Normalized and counts commands take the same deadband in units of the PWM frame
    (d = deadband_us / pwm_span_us of full command).

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
    map : {"identity", "linear", "quadratic", "mixed", "t200"}, default "identity"
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
    deadband_us : float, default 0.0
        Half-width of the deadband about ``pwm_neutral_us``, us, in [0, pwm_span_us);
        linear, quadratic and mixed maps only (a catalogue map has its own).
    quadratic_share : float or None, default None
        q of the ``mixed`` map's shape, in [0, 1]; required by ``mixed``, refused by the
        other maps.

    Raises
    ------
    usvlog.errors.ConfigError
        If ``map`` is unknown, a length, force or span is not positive, a catalogue map
        has no ``supply_v`` or one outside its published range, a reversed flag is not
        a bool, a deadband is out of range or on a map that takes none, or
        ``quadratic_share`` is missing, out of range or given to a map other than
        ``mixed``.
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
    deadband_us: float = 0.0       # half-width of the deadband about neutral, us (shaped maps)
    quadratic_share: float | None = None   # q of the mixed map's shape (1 - q) x + q x|x|

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
        self._check_shape()

    def _check_shape(self) -> None:
        """``deadband_us`` and ``quadratic_share`` checked against the map."""
        db = self.deadband_us
        if isinstance(db, bool) or not isinstance(db, (int, float)) or not math.isfinite(db):
            raise ConfigError(f"thruster deadband_us = {db!r} must be a number of us")
        if db != 0.0:
            if self.map not in SHAPED_MAPS:
                own = "has its own deadband" if self.catalogue else "takes commands in newtons"
                raise ConfigError(f"thruster deadband_us = {db:g}: the {self.map} map {own}; a deadband is for "
                                  f"the {', '.join(SHAPED_MAPS)} maps")
            if not (0.0 <= db < self.pwm_span_us):
                raise ConfigError(f"thruster deadband_us = {db:g} must be >= 0 and below pwm_span_us = "
                                  f"{self.pwm_span_us:g} (a half-width about the neutral command, us)")
        q = self.quadratic_share
        if self.map == "mixed":
            if isinstance(q, bool) or not isinstance(q, (int, float)) or not (0.0 <= q <= 1.0):
                raise ConfigError(f"thruster map \"mixed\" needs quadratic_share in [0, 1] (its shape (1 - q) c + "
                                  f"q c|c|), not {q!r}")
        elif q is not None:
            raise ConfigError(f"thruster quadratic_share = {q!r} is for map = \"mixed\", not {self.map!r}")

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
        shape = self.shape(self.beyond_deadband(c))
        return np.where(c >= 0, self.forward_n * shape, self.reverse_n * shape)

    def force_to_command(self, force, unit: str, full_scale: float | None = None, side: str | None = None):
        """Force in newtons -> command in ``unit`` (saturated to the thruster limits).

        Inverse of :meth:`command_to_force` within the limits. For a catalogue map or a
        map with a deadband (``deadband_us``), zero force gives the neutral command (the
        middle of the deadband) and a non-zero force the command at the deadband's edge
        or beyond.

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
            y = f / np.where(f >= 0, self.forward_n, self.reverse_n)
            c = self._from_beyond(self._inverse_shape(y))
        c = self.direction(side) * np.asarray(c, dtype=float)
        if unit == "normalized":
            return c
        if unit == "pwm_us":
            return self.pwm_neutral_us + self.pwm_span_us * c
        return _full_scale(full_scale) * c

    @property
    def share(self) -> float:
        """q of the map's shape (1 - q) x + q x|x|: 0 linear, 1 quadratic, ``quadratic_share`` mixed.

        Raises
        ------
        usvlog.errors.ConfigError
            If the map has no such shape (identity or a catalogue map).
        """
        if self.map == "linear":
            return 0.0
        if self.map == "quadratic":
            return 1.0
        if self.map == "mixed":
            return float(self.quadratic_share)   # type: ignore[arg-type]  # checked in __post_init__
        raise ConfigError(f"thruster map {self.map!r} has no shape of its own ({', '.join(SHAPED_MAPS)} have)")

    def shape(self, x):
        """The map's shape s(x) = (1 - q) x + q x|x| (q = :attr:`share`), per unit of full command.

        Parameters
        ----------
        x : float or array_like
            Command beyond the deadband, in [-1, 1] (:meth:`beyond_deadband`).

        Returns
        -------
        numpy.ndarray
            s(x), odd, s(1) = 1, of the input's shape.
        """
        x = np.asarray(x, dtype=float)
        q = self.share
        return (1.0 - q) * x + q * x * np.abs(x)

    def beyond_deadband(self, c):
        """Normalized command -> the command beyond the deadband, x = sign(c) (|c| - d) / (1 - d).

        d = ``deadband_us`` / ``pwm_span_us``; 0 within the deadband, +-1 at full command.

        Parameters
        ----------
        c : float or array_like
            Normalized command as the thruster sees it (:meth:`normalize`), in [-1, 1].

        Returns
        -------
        numpy.ndarray
            x, of the input's shape (``c`` itself without a deadband).
        """
        c = np.asarray(c, dtype=float)
        d = self.deadband_us / self.pwm_span_us
        if d == 0.0:
            return c
        return np.sign(c) * np.maximum(np.abs(c) - d, 0.0) / (1.0 - d)

    def _inverse_shape(self, y):
        """x with s(x) = y (y in [-1, 1]): the root of (1 - q)|x| + q x^2 = |y|, signed."""
        y = np.asarray(y, dtype=float)
        q = self.share
        a = np.abs(y)
        if q == 0.0:
            x = a
        else:   # the positive root, written to stay accurate as q -> 0 (0 at a = 0, also for q = 1)
            den = (1.0 - q) + np.sqrt((1.0 - q) ** 2 + 4.0 * q * a)
            x = np.divide(2.0 * a, den, out=np.zeros_like(a), where=den > 0)
        return np.sign(y) * x

    def _from_beyond(self, x):
        """Inverse of :meth:`beyond_deadband`: zero is the neutral command, any other x the
        command at the deadband's edge or beyond."""
        x = np.asarray(x, dtype=float)
        d = self.deadband_us / self.pwm_span_us
        if d == 0.0:
            return x
        return np.where(x == 0.0, 0.0, np.sign(x) * (d + np.abs(x) * (1.0 - d)))

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
