"""The reverse-to-forward thrust ratio of runs whose thrust is in command units.

In command units (a thruster map with forward_n = 1 and reverse_n = rho,
:func:`command_unit_vessel`), eq. (3) divided by the forward gain is linear in the per-unit
model and in the ratio rho (:mod:`usvlog.identify.thrust_scale` says why). :func:`reverse_ratio`
estimates rho by equation error; :func:`profile_ratio` (the paper's model) and
:func:`profile_ratio_ext` (the extended one) refine it by output error, each cost a fit with
the parameters refitted at that ratio. The run's thrust at a ratio is s+ + rho s-
(:func:`with_ratio`), made from two runs' thrust at rho = 1 and 2, so a new ratio costs no new
thrust map.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from ..errors import ConfigError, FitFailed
from ..log.fieldlog import FieldLog
from ..model.thrusters import SHAPED_MAPS
from ..model.vessel import PARAM_NAMES, ExtendedParams, Vessel, VesselParams
from .data import run_data
from .equation import regressors
from .smooth import derivative, kinematic_states, smooth_like, thrust_on_grid

SCALE_FREE = ("xg",)
"""Parameters the thrust gain does not scale (lengths)."""

EXT_PROFILE_SPAN_S = 240.0     # the extended ratio search fits the first this many seconds of each run
EXT_RATIO_STEP = 1.3   # step of the extended model's coarse grid of reverse/forward ratios (factor)
EE_ACC_S = 6.0  # smoothing window (s) of the ratio's equation-error fit, as the identifier's


def command_unit_vessel(vessel: Vessel, ratio: float) -> Vessel:
    """The vessel with thrusters in command units: forward_n = 1, reverse_n = ``ratio``.

    Parameters
    ----------
    vessel : Vessel
        Gives the arm, the map shape (``identity`` and a catalogue map become ``linear``),
        its deadband and PWM settings.
    ratio : float
        Reverse-to-forward gain ratio, > 0.

    Returns
    -------
    Vessel
        Thrusters ``scale = "command"``, ``known = true``; the model unchanged.
    """
    t = vessel.thrusters
    if t.map in SHAPED_MAPS:
        return replace(vessel, thrusters=replace(t, forward_n=1.0, reverse_n=float(ratio), known=True,
                                                 scale="command"))
    return replace(vessel, thrusters=replace(t, map="linear", forward_n=1.0, reverse_n=float(ratio), known=True,
                                             scale="command", deadband_us=0.0, quadratic_share=None))


def without_logged_forces(log: FieldLog) -> FieldLog:
    """A copy of ``log`` whose ``/thrust/command`` has no logged forces (they were a guess)."""
    out = log.copy()
    fr = out["/thrust/command"].copy()
    for c in ("thrust_left_n", "thrust_right_n"):
        if c in fr:
            fr[c] = np.nan
    out.channels["/thrust/command"] = fr
    return out


def reverse_ratio(logs: list[FieldLog], vessel: Vessel, model: str = "paper") -> tuple[float, str]:
    """Reverse-to-forward thrust gain ratio by equation error in command units.

    Surge and yaw of eq. (3) divided by the forward gain are linear in (m, m xg, Iz, d11,
    d33) per unit and in the ratio rho: A theta - rho s- = s+. Solved by least squares,
    each equation weighted by its residual scatter (two passes). For the extended model the
    same with its surge and yaw regressors (m11, m22, m26, m66, d11, d11q, d33, d33q per
    unit; :func:`usvlog.identify.extended.ext_regressors`): on a boat with quadratic damping
    the paper's linear terms would absorb part of the reverse thrust and bias the ratio.

    Parameters
    ----------
    logs : list of FieldLog
        Runs with ``/thrust/command`` (commands), ``/gnss/fix`` and ``/compass/heading``.
    vessel : Vessel
        Arm and map shape.
    model : {"paper", "extended"}, default "paper"
        The model whose regressors carry the per-unit terms.

    Returns
    -------
    ratio : float
        rho > 0; the vessel's own reverse_n / forward_n when the runs have too little
        reverse thrust to tell (or the estimate is not positive).
    source : str
        ``"equation error"`` or ``"vessel"``.
    """
    rows_A, rows_p, rows_n = [], [], []
    for log in logs:
        log = without_logged_forces(log)
        r1 = run_data(log, command_unit_vessel(vessel, 1.0))
        r2 = run_data(log, command_unit_vessel(vessel, 2.0))
        ks = kinematic_states(log, r1, vessel)
        nu = ks.nu((0.0, 0.0))
        t = ks.t
        s1, s2 = thrust_on_grid(r1, t), thrust_on_grid(r2, t)
        neg = [smooth_like(t, b - a, EE_ACC_S) for a, b in zip(s1, s2)]        # s-: (tau_u, tau_r)
        pos = [smooth_like(t, 2 * a - b, EE_ACC_S) for a, b in zip(s1, s2)]    # s+
        nu_s, nu_d = smooth_like(t, nu, EE_ACC_S), derivative(t, nu, EE_ACC_S)
        if model == "paper":
            rows_A.append(regressors(nu_s, nu_d)[[0, 2]][:, :, [0, 1, 2, 3, 5]])
        else:   # the sway damping d22, d22q has no surge or yaw column
            from .extended import ext_regressors  # lazy: the extended model only

            rows_A.append(ext_regressors(nu_s, nu_d)[[0, 2]][:, :, [0, 1, 2, 3, 4, 5, 8, 9]])
        rows_p.append(np.stack(pos))
        rows_n.append(np.stack(neg))
    A = np.concatenate(rows_A, 1)
    sp = np.concatenate(rows_p, 1)
    sn = np.concatenate(rows_n, 1)
    fallback = vessel.thrusters.reverse_n / vessel.thrusters.forward_n
    total = np.abs(sp).sum() + np.abs(sn).sum()
    if total == 0 or np.abs(sn).sum() < 0.02 * total:
        return float(fallback), "vessel"
    X = np.concatenate([A, -sn[:, :, None]], 2)       # (2, N, 6)
    ok = np.isfinite(X).all(axis=(0, 2)) & np.isfinite(sp).all(axis=0)
    if ok.sum() < 2 * X.shape[2]:   # too few finite samples (gaps in the smoothed states)
        return float(fallback), "vessel"
    X, sp = X[:, ok], sp[:, ok]
    w = np.ones(2)
    for _ in range(2):
        Xw = (X * w[:, None, None]).reshape(-1, X.shape[2])
        yw = (sp * w[:, None]).reshape(-1)
        sol = np.linalg.lstsq(Xw, yw, rcond=None)[0]
        res = sp - X @ sol
        w = 1.0 / np.maximum(np.sqrt(np.mean(res ** 2, axis=1)), 1e-12)
    rho = float(sol[-1])
    if not (math.isfinite(rho) and rho > 0):
        return float(fallback), "vessel"
    return rho, "equation error"


def _pm_runs(logs: list[FieldLog], vessel: Vessel):
    """Per log: (RunData at rho = 1, its s+ and s- thrust (tau_u, tau_r) on the thrust grid, kinematic states)."""
    out = []
    for log in logs:
        log = without_logged_forces(log)
        r1 = run_data(log, command_unit_vessel(vessel, 1.0))
        r2 = run_data(log, command_unit_vessel(vessel, 2.0))
        neg = (r2.tau_u - r1.tau_u, r2.tau_r - r1.tau_r)
        pos = (r1.tau_u - neg[0], r1.tau_r - neg[1])
        out.append((r1, pos, neg, kinematic_states(log, r1, vessel)))
    return out


def with_ratio(r1, pos, neg, rho: float):
    """The run's thrust in command units for reverse-to-forward ratio ``rho``: s+ + rho s-."""
    return replace(r1, tau_u=pos[0] + rho * neg[0], tau_r=pos[1] + rho * neg[1])


def profile_ratio(logs: list[FieldLog], vessel: Vessel, rho0: float, *, free_mask, fit_current: bool,
                  segment_s: float, fix_theta=None, rel_tol: float = 0.003,
                  max_eval: int = 8) -> tuple[float, np.ndarray]:
    """Reverse-to-forward ratio minimising the output-error cost (parameters refitted at each).

    A parabola through the three best (ratio, cost) points, from ``rho0`` and +-10 %, moved
    until the ratio changes by less than ``rel_tol``. Each cost is an output-error fit of the
    per-unit model (one stage, the stated sensor noise as weights so costs compare), started
    from the best fit so far.

    Parameters
    ----------
    logs : list of FieldLog
    vessel : Vessel
        Arm and map shape.
    rho0 : float
        Starting ratio (equation error), > 0.
    free_mask : array_like of bool, shape (6,)
        Which per-unit parameters are fitted (PARAM_NAMES order).
    fit_current : bool
        Fit a current per run.
    segment_s : float
        Multiple-shooting segment length, s.
    fix_theta : array_like, shape (6,), optional
        Values of the parameters not fitted (default the vessel's).
    rel_tol : float, default 0.003
        Relative change of the ratio that ends the search.
    max_eval : int, default 8
        Most output-error fits.

    Returns
    -------
    rho : float
        The ratio, > 0.
    theta : numpy.ndarray, shape (6,)
        The per-unit parameters of the best fit (PARAM_NAMES order).
    """
    from .output import fit_output_error  # local: the output-error fit is only needed by this search

    data = _pm_runs(logs, vessel)
    kin = [d[3] for d in data]
    free = np.asarray(free_mask, bool)
    base = np.asarray(fix_theta if fix_theta is not None else vessel.params.as_array(), float)
    theta = _ee_start(data, rho0, free, base)
    best: dict[str, Any] = {"cost": np.inf, "theta": theta, "cur": np.zeros((len(logs), 2))}

    def cost(rho: float, first: bool) -> float:
        runs = [with_ratio(d[0], d[1], d[2], rho) for d in data]
        try:
            oe = fit_output_error(runs, best["theta"], lambda i, t: kin[i].at(t), free_mask=free,
                                  fit_current=fit_current, currents0=best["cur"], segment_s=segment_s,
                                  warm_segment_s=0.0, reweight=False, max_nfev=60 if first else 20)
        except FitFailed:   # no fit at this ratio: it is not the one
            return np.inf
        c = float(oe.sigma2) if np.all(np.isfinite(oe.theta)) and np.isfinite(oe.sigma2) else np.inf
        if c < best["cost"]:
            best.update(cost=c, theta=oe.theta, cur=oe.currents)
        return c

    rho = _parabola_search(cost, rho0, rel_tol, max_eval)
    return rho, np.asarray(best["theta"], float)


def profile_ratio_ext(logs: list[FieldLog], vessel: Vessel, rho0: float, *, fit_current: bool,
                      max_current_mps: float, segment_s: float) -> tuple[float, np.ndarray]:
    """:func:`profile_ratio` for the extended model: each cost an extended output-error fit.

    Its own search, not the paper model's: on a boat of the extended form (different surge and
    sway inertia, quadratic damping) the paper model buys part of the missing terms with a wrong
    ratio (0.37 for a true 0.56 on the shipped catamaran), while the extended fit's cost is least
    near the true ratio. Its fits stall from a poor start (a stalled fit only raises the
    cost), so every fit starts afresh from the paper model's equation error per unit of command
    at its own ratio, in the extended form, with short shooting segments, and the search is
    grids, not a line search a stalled fit would mislead: ``rho0`` times EXT_RATIO_STEP^k
    (k = -3..3: equation error's ratio is biased by the smoother on a boat with second time
    constants), then steps of EXT_RATIO_STEP^(1/4) (k = -3..3) and EXT_RATIO_STEP^(1/16)
    (k = -2..2) about the best so far; the best fit seen is returned (17 fits, a resolution
    of 1.7 % in the ratio). The fits use the first EXT_PROFILE_SPAN_S of each run: on a
    ten-minute run with quiet sensors the fits over all of it stalled at every ratio (the
    search found 0.27 for a true 0.56), and the cost stays that of a few minutes of data.

    Parameters
    ----------
    logs : list of FieldLog
    vessel : Vessel
        Arm and map shape; its paper terms per unit of its forward force are the fallback start.
    rho0 : float
        Starting ratio, > 0.
    fit_current : bool
        Fit a current per run.
    max_current_mps : float
        Bound on each current component, m/s.
    segment_s : float
        Multiple-shooting segment length, s.
    Returns
    -------
    rho : float
        The ratio, > 0.
    theta : numpy.ndarray, shape (10,)
        The per-unit extended parameters of the best fit (EXTENDED_PARAM_NAMES order), on the
        first EXT_PROFILE_SPAN_S of the runs.
    """
    from .extended_oe import ext_physical_problem, fit_extended_output_error  # local: only this search

    data = [_first_part(r1, pos, neg, ks, EXT_PROFILE_SPAN_S) for r1, pos, neg, ks in _pm_runs(logs, vessel)]
    kin = [d[3] for d in data]
    base = vessel.params.as_array()
    base[[PARAM_NAMES.index(k) for k in PARAM_NAMES if k not in SCALE_FREE]] /= vessel.thrusters.forward_n

    def start(rho: float) -> np.ndarray:
        return _ext_start(_ee_start(data, rho, np.ones(len(PARAM_NAMES), bool), base), base)

    counts = [(2 * len(d[0].t_gps), len(d[0].t_compass)) for d in data]
    best: dict[str, Any] = {"cost": np.inf}

    def cost(rho: float) -> float:
        runs = [with_ratio(d[0], d[1], d[2], rho) for d in data]
        try:
            oe = fit_extended_output_error(runs, kin, start(rho), fit_current=fit_current,
                                           max_current_mps=max_current_mps, segment_s=segment_s, max_iter=60)
        except FitFailed:   # no fit at this ratio: it is not the one
            return math.inf
        # the whitened sum of squares (the residuals' RMS per sensor times their counts)
        c = sum(n_g * oe.rms["gps"] ** 2 + n_c * oe.rms["compass"] ** 2 for n_g, n_c in counts)
        c = c if math.isfinite(c) and not oe.diverged and not ext_physical_problem(oe.theta) else math.inf
        if c < best["cost"]:
            best.update(cost=c, theta=oe.theta, rho=rho)
        return c

    # a coarse grid, then two finer ones about the best ratio so far: a fit that stalls only
    # raises its cost, so the least cost seen is near the true ratio unless every fit near it stalls
    for stage, (step, span) in enumerate(((EXT_RATIO_STEP, 3), (EXT_RATIO_STEP ** 0.25, 3),
                                          (EXT_RATIO_STEP ** 0.0625, 2))):
        centre = best.get("rho", rho0)
        for k in range(-span, span + 1):
            if k or not stage:   # the centre's fit is known after the first grid
                cost(centre * step ** k)
        if "rho" not in best:   # every fit failed
            return float(rho0), start(rho0)
    return float(best["rho"]), np.asarray(best["theta"], float)


def _first_part(r1, pos, neg, ks, span_s: float):
    """The first ``span_s`` seconds of a run's (RunData, s+, s-, KinStates)."""
    t_hi = r1.t_thrust[0] + span_s
    k = r1.t_thrust <= t_hi
    return (r1.window(-np.inf, t_hi), tuple(a[k] for a in pos), tuple(a[k] for a in neg), ks.window(-np.inf, t_hi))


def _ext_start(th, base) -> np.ndarray:
    """An extended-model start from the paper model's per-unit equation-error values ``th``
    (PARAM_NAMES order), each where plausible: within a factor 3 of the vessel's per-unit
    ``base`` scaled to the fitted m (the gain is unknown: the vessel's ratios to m are the
    prior), else that; written in the extended form (:meth:`ExtendedParams.from_paper`)."""
    m = PARAM_NAMES.index("m")
    prior = base * np.where([k in SCALE_FREE for k in PARAM_NAMES], 1.0, th[m] / base[m] if th[m] > 0 else 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.isfinite(th) & (th > 0) & (th / prior > 1 / 3) & (th / prior < 3)
    ok[PARAM_NAMES.index("xg")] = bool(np.isfinite(th[-1]) and abs(th[-1]) < 1.0)
    th = np.where(ok, th, prior)
    if th[1] - th[0] * th[-1] ** 2 <= 0.05 * th[1]:   # Iz - m xg^2 > 0 kept (as the identifier's start)
        th[-1] = 0.0
    try:
        return ExtendedParams.from_paper(VesselParams(**dict(zip(PARAM_NAMES, map(float, th))))).as_array()
    except ConfigError:   # not a boat: the vessel's values per unit
        return ExtendedParams.from_paper(VesselParams(**dict(zip(PARAM_NAMES, map(float, base))))).as_array()


def _ee_start(data, rho: float, free, base) -> np.ndarray:
    """The paper model's equation-error fit per unit of command at ratio ``rho`` (the values
    not ``free`` held at ``base``); ``base`` where it fails."""
    from .equation import fit_equation_error  # local: only the ratio searches need a start from it

    nus, nuds, tus, trs = [], [], [], []
    try:
        for r1, pos, neg, ks in data:
            nu = ks.nu((0.0, 0.0))
            tu, tr = thrust_on_grid(with_ratio(r1, pos, neg, rho), ks.t)
            nus.append(smooth_like(ks.t, nu, EE_ACC_S))
            nuds.append(derivative(ks.t, nu, EE_ACC_S))
            tus.append(smooth_like(ks.t, tu, EE_ACC_S))
            trs.append(smooth_like(ks.t, tr, EE_ACC_S))
        ee = fit_equation_error(np.concatenate(nus), np.concatenate(nuds), np.concatenate(tus),
                                np.concatenate(trs),
                                fix={k: float(base[i]) for i, k in enumerate(PARAM_NAMES) if not free[i]})
    except FitFailed:   # too short to smooth, too few finite samples: the base values
        return base.copy()
    return np.where(free, ee.theta, base) if ee.valid else base.copy()


def _parabola_search(cost, rho0: float, rel_tol: float, max_eval: int) -> float:
    """The ratio of least ``cost(rho, first)``: ``rho0`` and +-10 %, then the vertex of a
    parabola through the three best points (kept within half and 1.5 times their span) until
    it moves by less than ``rel_tol`` or ``max_eval`` costs were taken."""
    seen: dict[float, float] = {}
    for rho in (rho0, 0.9 * rho0, 1.1 * rho0):
        seen[rho] = cost(rho, not seen)
    rho = min(seen, key=lambda k: seen[k])
    while len(seen) < max_eval:
        finite = [kv for kv in seen.items() if math.isfinite(kv[1])]
        if len(finite) < 3:   # failed fits (infinite cost) give no parabola: the best seen
            break
        pts = sorted(finite, key=lambda kv: kv[1])[:3]
        x = np.array([p[0] for p in pts])
        y = np.array([p[1] for p in pts])
        a, b, _ = np.polyfit(x, y, 2)
        lo, hi = 0.5 * x.min(), 1.5 * x.max()
        new = float(np.clip(-b / (2 * a), lo, hi)) if a > 0 else float(x[0] + (x[0] - x[-1]))
        new = max(new, 1e-3)
        if abs(new - x[0]) <= rel_tol * x[0] or any(abs(new - k) <= 1e-4 * k for k in seen):
            rho = new if a > 0 else float(x[0])
            break
        seen[new] = cost(new, False)
        rho = min(seen, key=lambda k: seen[k])
    return float(rho)


__all__ = ["SCALE_FREE", "command_unit_vessel", "profile_ratio", "profile_ratio_ext", "reverse_ratio",
           "with_ratio", "without_logged_forces"]
