"""The identifier's verdict: ``usable``, ``usable with caveats`` or ``unusable``, and why.

:func:`_verdict` collects findings, each with a level (note, caveat, unusable): the validation
fit % (a free run, else 30 s ahead), parameters whose standard errors are wide or could not be
computed, strong correlations, the condition number, the extended model's own terms, currents
at their bound, dead channels, an unknown thrust scale, outliers and residuals, and the bias
of equation error. The worst level is the verdict; the reasons are listed worst first. The
thresholds are the constants below. The functions taking ``self`` are methods of
:class:`~usvlog.identify.identifier.Identifier`, kept here with the job they do.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..choices import EXTENDED_PARAM_NAMES
from ..model.vessel import PARAM_NAMES
from .ahead import WHITENESS_STEP_S
from .candidates import QS_HELD
from .checks import _excitation_warnings, _why_dead
from .smoother_bias import biased

# typing only: the class whose methods these are (it imports this module)
if TYPE_CHECKING:
    from .identifier import Identifier


VERDICTS = ("usable", "usable with caveats", "unusable")
# verdict thresholds: validation fit % of u and r; relative standard error of m, Iz, d11, d33
FIT_UNUSABLE, FIT_CAVEAT = 0.0, 50.0
U_FIT_UNUSABLE = -50.0      # u: its measurement noise alone can cost tens of points
REL_SE_CAVEAT, REL_SE_UNUSABLE = 0.10, 0.3
# a surge or yaw time constant (inertia / damping) below this is no boat's (small USVs: about a second and
# more; the paper's vessel 6.6 s in surge, a Fossen Otter 1.1 s): the inertia was not determined
MIN_TIME_CONSTANT_S = 0.1
COND_CAVEAT = 1e5
NOTABLE_CURRENT_MPS = 0.1   # a current another candidate fitted that a returned equation-error fit lacks


def fmt_num(x: float, digits: int = 4) -> str:
    """A number for people: ``digits`` significant digits, no endless digit strings."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x:.{digits}g}"


def fmt_pct(x: float) -> str:
    """A fit % for people: one decimal; below -999 only ``< -999`` (the figure means nothing
    more); ``n/a`` when not finite."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return "< -999" if x < -999 else f"{x:.1f}"


def _signed_pct(rel: float) -> str:
    """A signed relative change for people: whole percent, ``> +999 %`` / ``< -999 %`` beyond."""
    if not abs(rel) <= 9.99:
        return "> +999 %" if rel > 0 else "< -999 %"
    return f"{100 * rel:+.0f} %"


def _rel_pct(rel: float) -> str:
    """A relative standard error for people: whole percent, ``> 999 %`` beyond (it means nothing more)."""
    return "> 999 %" if not math.isfinite(rel) or rel > 9.99 else f"{100 * rel:.0f} %"


# ------------------------------------------------------------------------------
def _held_names(self: Identifier) -> set:
    """Names held at a fixed value: the fixed ones, and for the extended model the paper terms
    they are (m11 is m, m66 is Iz; ``--fix m`` holds m11)."""
    held = set(self.fix)
    for paper, ext in (("m", "m11"), ("Iz", "m66")):
        if paper in held or ext in held:
            held |= {paper, ext}
    return held


def _ext_term_findings(self: Identifier, add) -> None:
    """The extended model's own terms judged by their standard errors (the paper-term checks
    see only their combinations): m22 poorly determined is a caveat (sway barely excited);
    the split of linear and quadratic damping, and m26, are notes (their combination at the
    typical speed, the paper term, is what the checks above judge)."""
    ext = self.extended_
    assert ext is not None
    vals = ext.to_dict()
    # the quadratic-surge form holds these at m11's value or 0: not terms of its own
    tied = set(QS_HELD) if self.final_.start.quadratic_surge else set()
    for k in EXTENDED_PARAM_NAMES:
        v, se = vals[k], self.extended_stderr_.get(k, math.nan)
        if k in ("m11", "m66") or (k.endswith("q") and v <= 0) or k in self.fix or k in tied:
            continue   # m, Iz: judged above; q at its bound 0; fixed; tied
        if not (math.isfinite(se) and se > 1e-9 * max(abs(v), 1e-300)):
            add(1 if k == "m22" else 0, f"extended term {k} = {fmt_num(v)}: standard error not computable")
            continue
        rel = se / abs(v) if v else math.inf
        if rel > REL_SE_CAVEAT:
            add(1 if k == "m22" else 0, f"extended term {k} poorly determined: {fmt_num(v)} +- {fmt_num(se, 2)}"
                                        f" ({_rel_pct(rel)})")


def _smoother_bias_findings(self: Identifier, add) -> None:
    """The smoother's bias on a fit to smoothed states (:mod:`usvlog.identify.smoother_bias`): a
    parameter the model's own smoothed motion does not give back within REL_SE_CAVEAT is a
    caveat, beyond REL_SE_UNUSABLE unusable for m, Iz, d11, d33 (as a standard error that
    large: the value returned is that far from the boat's, and its interval does not say so)."""
    sw = getattr(self, "bias_switch_", None)
    if sw:
        add(0, f"{sw['from']} (score {fmt_pct(sw['score'])}) fitted again on its own smoothed motion gives "
               f"{sw['param']} {_signed_pct(sw['bias'])} (the smoother biases it): {self.chosen_.start.name}, "
               "which validates about as well and is not biased so, returned")
    bias = getattr(self, "smoother_bias_", {}) or {}
    for k in ("m", "Iz", "d11", "d22", "d33"):
        b = bias.get(k)
        if b is None or not abs(b) > REL_SE_CAVEAT:
            continue
        level = 2 if k in biased(bias) else 1
        add(level, f"{k} biased by the smoother: the model's own motion, as the sensors and the smoother show it, "
                   f"fitted again gives {k} {_signed_pct(b)}: this fit does not recover {k} through the smoother, so "
                   f"the {k} returned ({fmt_num(getattr(self.params_, k))}) may be off by as much (the smoothed "
                   "velocities round off changes faster than the GNSS and compass resolve; a higher GNSS rate "
                   "avoids it)")


def _verdict(self: Identifier, vessel, runs, kin) -> tuple[list[str], str]:
    """(reasons, verdict): each finding with its level, the worst level the verdict."""
    found: list[tuple[int, str]] = []   # (0 note, 1 caveat, 2 unusable, text)
    unchecked = True   # nothing validates the model: no validation, or one that excites neither u nor r

    def add(level: int, text: str) -> None:
        found.append((level, text))

    p = self.params_
    # -- validation ------------------------------------------------------------
    if self.validations_:
        fp = self.validation_fit_percent_()
        on = {"holdout": "the held-out data", "leave-one-out": "the left-out logs"}.get(
            self.validation_mode_, "the validation log(s)")
        exc = getattr(self, "excitation_", {}) or {}
        excited = {ch: e.excited for ch, e in exc.items()}
        # a channel the held-out data move no more than its noise has a fit % of noise: not judged
        # (its figure is shown as "not excited there"), and what it determines is not validated
        quiet = [ch for ch in ("u", "r") if excited.get(ch) is False]
        unchecked = len(quiet) == 2
        fu = math.inf if "u" in quiet else fp["u"] if math.isfinite(fp["u"]) else -math.inf
        fr = math.inf if "r" in quiet else fp["r"] if math.isfinite(fp["r"]) else -math.inf
        txt = f"validation fit on {on}: " + ", ".join(
            f"{ch} not excited there" if ch in quiet else f"{ch} {fmt_pct(fp[ch])} %" for ch in ("u", "r"))
        if quiet:
            # a note while the other channel validates the model (what the quiet one determines is
            # judged by its standard errors above the fit); nothing validated at all is a caveat
            which = {"u": "m, d11", "r": "Iz, d33"}
            add(1 if len(quiet) == 2 else 0, f"{on} barely excite " + " and ".join(
                f"{ch} (spread {fmt_num(exc[ch].spread, 2)}, its noise {fmt_num(exc[ch].noise, 2)} "
                f"{'m/s' if ch == 'u' else 'rad/s'})" for ch in quiet)
                + ": " + "; ".join(which[ch] for ch in quiet) + " not validated there")
        ahead = (getattr(self, "fit_percent_ahead_", {}) or {}).get("30")
        # the measured u, v, r are smoothed GPS and compass: their own noise caps the fit %
        # of u (slow, small changes) far below 100 even for the true model; r is the sharp test.
        # The free run over the whole held-out part is judged first; a model that fails it but
        # predicts 30 s ahead (re-started from the smoothed state, a path follower's horizon)
        # is usable with that caveat, not refused
        ok_ahead = ahead is not None and all(
            excited.get(ch) is False or (math.isfinite(ahead[ch]) and ahead[ch] >= FIT_CAVEAT) for ch in ("u", "r"))
        if fr < FIT_UNUSABLE or fu < U_FIT_UNUSABLE:
            if ok_ahead and ahead is not None:
                add(1, f"{txt} in a free run, but {fmt_pct(ahead['u'])} % and {fmt_pct(ahead['r'])} % predicted "
                       f"30 s ahead (judged at that horizon: a path follower needs the model over its "
                       f"prediction horizon, not over minutes of disturbances)")
            else:
                add(2, f"{txt}: the model predicts worse than a constant; it does not describe this boat")
        elif fr < FIT_CAVEAT or fu < FIT_UNUSABLE:
            add(1, f"{txt}: the model explains only part of the motion")
        if ahead is not None and not (fr < FIT_UNUSABLE or fu < U_FIT_UNUSABLE):
            # the free run passed, yet restarted from the measured state every 30 s a channel is
            # predicted worse than a constant: what that channel determines is not validated
            bad = [ch for ch in ("u", "r") if ch not in quiet and math.isfinite(ahead[ch]) and ahead[ch] < FIT_UNUSABLE]
            if bad:
                which = {"u": "m, d11", "r": "Iz, d33"}
                add(1, "predicted 30 s ahead, " + " and ".join(f"{ch} {fmt_pct(ahead[ch])} %" for ch in bad)
                       + " (worse than a constant): " + "; ".join(which[ch] for ch in bad)
                       + " not validated by the held-out data")
        wh = (getattr(self, "whiteness_", {}) or {}).get("r")
        if wh is not None and not wh.white:
            add(1, f"the yaw rate predicted {WHITENESS_STEP_S:g} s ahead leaves correlated residuals ({wh.outside} of "
                   f"{len(wh.lags)} lags outside the 99 % bounds, {wh.allowed} allowed): yaw dynamics the model does "
                   "not explain (quadratic damping, a thruster lag; --model extended may)")
        sw = getattr(self, "loo_switch_", None)
        if sw:
            add(0, f"left out in turn, the logs validate equation error better (score "
                   f"{fmt_pct(sw['equation_error_score'])}) than {sw['from']} ({fmt_pct(sw['score'])}): "
                   f"equation error returned")
        elif getattr(self, "_loo_prefers_ee", False):
            add(1, "left out in turn, the logs validate equation error better than the fit returned")
    else:
        add(1, "not validated (--no-validate): nothing checks the model on data it was not fitted on")
    # -- the parameters -----------------------------------------------------------
    held = self._held_names()
    se_bad = [k for k in PARAM_NAMES if k not in held and k != "xg" and
              not (math.isfinite(self.stderr_[k]) and self.stderr_[k] > 1e-9 * abs(getattr(p, k)))]
    if se_bad and self.method != "filter-error":
        add(2, f"standard errors of {', '.join(se_bad)} could not be computed (degenerate fit): "
               "the intervals mean nothing")
    rel = {k: self.stderr_[k] / abs(getattr(p, k)) if getattr(p, k) else math.inf for k in PARAM_NAMES}
    ex = _excitation_warnings(kin, force=rel["Iz"] > 0.2 or rel["d33"] > 0.2)
    for w in ex:
        add(1, w)
    for k in PARAM_NAMES:
        if k in held or k in se_bad:
            continue
        if rel[k] > REL_SE_CAVEAT and not (k == "xg" and abs(p.xg) < 0.05):
            level = 2 if rel[k] > REL_SE_UNUSABLE and k in ("m", "Iz", "d11", "d33") else 1
            add(level, f"{k} poorly determined: {fmt_num(getattr(p, k))} +- {fmt_num(self.stderr_[k], 2)} "
                       f"({_rel_pct(rel[k])})")
    _smoother_bias_findings(self, add)
    names = list(self.corr_.index)
    C = self.corr_.to_numpy()
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            wide = [n for n in (names[i], names[j]) if rel.get(n, 0.0) > REL_SE_CAVEAT]
            if abs(C[i, j]) >= 0.95 and wide:   # correlated and therefore uncertain
                add(1, f"{names[i]} and {names[j]} correlated at {C[i, j]:.2f}, so {', '.join(wide)} "
                       f"uncertain: excite the run differently or --fix one of them")
    if math.isfinite(self.cond_) and self.cond_ > COND_CAVEAT:
        add(1, f"condition number {fmt_num(self.cond_, 2)}: parameters nearly unidentifiable together")
    if self.extended_ is not None:
        self._ext_term_findings(add)
    iz_eff = p.Iz_eff
    if iz_eff <= 0:
        add(1, f"Theorem 3.1 condition 1 fails: Iz - m xg^2 = {fmt_num(iz_eff)} <= 0")
    for what, inertia, damping, terms, mass in (("surge", p.m, p.d11, "m, d11", "m"),
                                                ("yaw", iz_eff, p.d33, "Iz, d33", "Iz")):
        tc = inertia / damping if damping > 0 else math.inf
        if 0 < tc < MIN_TIME_CONSTANT_S and mass not in held:   # a held inertia is the user's
            # tolerated (a caveat) only where a validation shows the model predicts all the same
            add(2 if unchecked else 1, f"{what} time constant {fmt_num(tc, 2)} s ({terms}): no boat responds that "
                "fast; its inertia is not determined by this data (a fit to smoothed velocities pulls it towards zero)"
                + ("; and nothing validates the model" if unchecked else ""))
    lag = getattr(self, "thruster_lag_", None)
    if lag is not None:
        hi = lag.ci95[1]
        span = f"{lag.lag_s:.2f} s (95 % {lag.ci95[0]:.2f}..{'inf' if not math.isfinite(hi) else f'{hi:.2f}'} s)"
        if lag.at_bound or not math.isfinite(hi):
            add(1, f"thruster lag identified as {span}: the data ask for a lag as long as allowed or more, which is "
                   "rarely a thruster's; something else slows the response (a thrust map, saturation)")
        else:
            add(0, f"thruster lag identified: {span}, applied to the thrust the model was fitted on")
        if math.isfinite(lag.other_lag_s):
            add(1, f"a thruster lag of {lag.other_lag_s:.2f} s fits the data about as well as {lag.lag_s:.2f} s (the "
                   "lag's profile has two minima): the lag is not determined by these data; a known lag (--lag-s) "
                   "decides")
        t_surge = self.params_.m / self.params_.d11 if self.params_.d11 > 0 else math.inf
        if lag.lag_s > t_surge:
            # u = tau / (d11 (1 + s T_lag) (1 + s T_surge)): in surge the two time constants can be swapped
            add(1, f"thruster lag {lag.lag_s:.2f} s is longer than the surge time constant m / d11 = "
                   f"{t_surge:.2f} s: in surge a thruster lag and the hull's time constant are interchangeable "
                   "(two first-order lags in series), so the fit may have put the hull's inertia into the lag "
                   f"(m {self.params_.m:.3g} kg); a known lag (--lag-s) or a run with more turning decides")
    # -- the current -----------------------------------------------------------------
    for i, c in enumerate(self.current_):
        speed = math.hypot(*c)
        if max(abs(c[0]), abs(c[1])) >= 0.98 * self.max_current_mps:
            add(1, f"current of run {i} at its bound ({speed:.2f} m/s, bound {self.max_current_mps:g} m/s "
                   "per axis): the fit wanted more current than allowed; a model mismatch or a real strong "
                   "current (--max-current-mps)")
    if self.current and self.final_.start.kind == "equation-error" and not self.final_.start.ee_current:
        # plain equation error fits no current: say so when the fits that do found one
        others = [c for c in getattr(self, "candidates_", []) if not c.failed and c.start.kind != "equation-error"
                  and len(c.currents)]
        if others:
            best = max(others, key=lambda c: c.score)
            for i, cur in enumerate(best.currents):
                speed = math.hypot(*cur)
                if speed >= NOTABLE_CURRENT_MPS:
                    toward = math.degrees(math.atan2(cur[1], cur[0])) % 360.0
                    add(1, f"the returned fit (equation error) has no water current, and run {i} has one: "
                           f"{best.start.name} found {speed:.2f} m/s toward {toward:.0f} deg; the parameters "
                           "absorb it (identify a run without current, or --model extended)")
    # -- the data -------------------------------------------------------------------
    for lg_h, run in zip(self.health_, runs):
        dead = [t for t in (lg_h.get("dead") or []) if t in ("/compass/heading", "/gnss/fix", "/thrust/command")]
        for t in dead:
            add(2, f"{run.source}: {t} was judged dead at import ({_why_dead(lg_h, t)}): what it recorded "
                   "is not the boat's motion")
    unknown = [run.source for run, h in zip(runs, self.health_)
               if (h.get("thrust") or {}).get("force_scale") == "unknown"]
    guessed = not vessel.thrusters.known and any(r.thrust_source != "logged newtons" for r in runs)
    if not self.thrust_scale_.known:   # identified in command units (and the gain from a fixed value)
        add(1 if self.thrust_scale_.case == "command units" else 0, self.thrust_scale_.message())
        if getattr(self, "quadratic_surge", False):
            add(0, "the paper model with quadratic surge damping (--quadratic-surge) was not tried: the thrust "
                   "has no known force scale; with forces (logged newtons, or a thruster map such as "
                   "map = \"t200\" in the vessel file) it is")
    elif unknown or guessed:
        scale_fixed = any(k in self.fix for k in ("m", "Iz", "d11", "d22", "d33"))
        src = ", ".join(unknown) if unknown else "the thruster map"
        what = ("thrust has no known force scale" if unknown else
                "thruster map is only a guess (thrusters.known = false)")
        if scale_fixed:
            add(0, f"{what} ({src}): the scale comes from the fixed value(s)")
        else:
            add(1, f"{what} ({src}): m, Iz and the damping are known only up to the unknown thrust "
                   "gain; --fix a known value (e.g. a weighed mass)")
    skipped = sum(r.thrust_skipped for r in runs)
    if skipped:
        add(0, f"{skipped} thrust record(s) not finite: skipped (the command before each held)")
    if self.oe_ is not None and self.oe_.outliers:
        o = self.oe_.outliers
        if o["gps"] or o["compass"]:
            add(0, f"{o['gps']} GNSS fix(es) and {o['compass']} compass reading(s) beyond "
                   f"5 sigma of the fitted model dropped as outliers")
    if self.oe_ is not None:
        for s in ("gps", "compass"):
            v = self.residual_rms_.get(s, 0.0)
            if v > 2.0:
                add(1, f"{s} residuals {v:.1f} times their stated noise: model mismatch or sensor trouble")
    if self.final_.start.kind == "equation-error":
        add(1 if self.method == "equation-error" else 0,
            "equation error is biased by measurement noise in its regressors (inertia terms and d22 "
            "typically tens of percent off)" + ("" if self.method == "equation-error" else
                                                 ": it validated better than the output-error fits here"))
        if self.final_.start.model == "paper" and self.equation_error_.theta[3] <= 0.0 and "d22" not in self.fix:
            add(1, f"d22 at its bound 0 in equation error (not determined): the vessel's value "
                   f"{fmt_num(p.d22)} kept")
    if not self.current and self.method == "output-error":
        add(0, "current not fitted: a real current biases d11 and d22")
    level = max((lv for lv, _ in found), default=0)
    order = sorted(found, key=lambda x: -x[0])
    return [t for _, t in order], VERDICTS[min(level, 2)] if level else VERDICTS[0]
