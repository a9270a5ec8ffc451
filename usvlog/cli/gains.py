"""``usvlog gains``: Theorem 3.1's conditions, eig(A_e) and the bound (18) for a vessel and gains."""

from __future__ import annotations

from ..errors import ConfigError
from .common import print_json


def register(sub) -> None:
    p = sub.add_parser("gains", help="check controller gains against Theorem 3.1 (exit 1 when a condition fails)")
    p.add_argument("--gains", default="paper-circle",
                   help="gains TOML ([gains], [guidance]), a scenario file, or the name of a shipped "
                        "scenario (default: paper-circle, the paper's Section IV gains and vessel)")
    p.add_argument("--vessel", default=None,
                   help="vessel TOML (default: the scenario's [vessel] when --gains is a scenario, "
                        "else the paper's Section IV vessel)")
    p.add_argument("--q", default=None, help="Q of the Lyapunov equation: 6 comma-separated diagonal "
                                               "entries (default: identity)")
    p.add_argument("--delta", type=float, default=None, help="bound delta on the perturbation g(t, x_e) of (13)")
    p.add_argument("--theta", type=float, default=0.5, help="theta of (18), 0 < theta < 1 (default 0.5)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    gains, vessel = api.gains_and_vessel(args.gains, args.vessel or None)
    q = None
    if args.q:
        try:
            q = [float(x) for x in args.q.split(",")]
        except ValueError as err:
            raise ConfigError(f"--q {args.q!r}: not 6 comma-separated numbers") from err
        if len(q) != 6:
            raise ConfigError(f"--q {args.q!r}: needs 6 diagonal entries")
    res = api.gains(gains, vessel=vessel, q=q, delta=args.delta, theta=args.theta)
    if args.json:
        print_json(res.to_dict())
    else:
        p, g = vessel.params, gains
        print(f"vessel {vessel.name}: m={p.m:g} Iz={p.Iz:g} d11={p.d11:g} d22={p.d22:g} d33={p.d33:g} xg={p.xg:g}")
        print("gains: " + " ".join(f"{k}={v:g}" for k, v in g.to_dict().items()))
        print("Theorem 3.1:")
        for c in res.conditions:
            print(f"  {'ok  ' if c.holds else 'FAIL'} {c.name}: {c.expression}  ({c.value:.6g})")
        print("eigenvalues of A_e:")
        for z in res.eigenvalues:
            print(f"  {z.real:+.6f} {z.imag:+.6f}j")
        if res.P is not None:
            print(f"Theorem 3.2 (Q = {'identity' if q is None else 'diag(' + args.q + ')'}, theta = {res.theta:g}): "
                  f"c1 = {res.c1:.6g}, c2 = {res.c2:.6g}, c3 = {res.c3:.6g}, c4 = {res.c4:.6g}; "
                  f"bound (18) b = {res.bound_per_delta:.6g} delta"
                  + (f" = {res.bound:.6g}" if res.bound is not None else ""))
        print(res.verdict)
    return 0 if res.ok else 1
