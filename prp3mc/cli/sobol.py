"""``prp3mc sobol``: Sobol indices and Shapley effects at one pose, ranked next to the worst case."""

import math

from .._version import __version__
from ..errors import BudgetError
from ..kinematics.geometry import Geometry
from ..units import DISPLAY, OUTPUTS
from ..limits import sobol_estimate
from . import (EFFECTS_NOTE, provenance, add_budget, add_geometry, add_json, add_pose, add_progress, add_sampling, command,
               emit_json, nonnegative_int, positive_float, positive_int, probability, within_limits)

_KEYS = ("S1", "S1_conf", "ST", "ST_conf")
_SHAPLEY = ("Sh", "Sh_conf")


def _group(text: str) -> tuple[str, list[str]]:
    """``NAME=in1,in2`` as a user group."""
    name, sep, members = text.partition("=")
    if not sep or not name or not members:
        raise BudgetError(f"--group expects NAME=input,input,... got {text!r}")
    return name, [m.strip() for m in members.split(",") if m.strip()]


def _number(value: float):
    """A float for JSON: NaN (no worst-case contribution) becomes null."""
    return None if math.isnan(value) else float(value)


_UNDEFINED = "undefined (constant input)"


def _indices(r, i: int, k: int, name: str) -> dict:
    """S1, S1_conf, ST, ST_conf (and Sh, Sh_conf) of one output and name; null with a reason where undefined."""
    from ..sobol.indices import DEPENDENT_NOTE, sobol_indices
    keys = _KEYS + (_SHAPLEY if r.Sh is not None else ())
    if name in r.constant:
        return {**{key: None for key in keys}, "reason": "constant input: no variance to share"}
    out = {key: _number(float(getattr(r, key)[i, k])) for key in keys}
    if r.correlated:
        out["reason"] = DEPENDENT_NOTE
    return out


def _index_text(row, shapley: bool, constant: tuple) -> str:
    width = 33 + 16 * shapley
    if row.kind == "shift":
        return f"{'known shift: no variance':>{width}s}"
    if row.name in constant:
        return f"{_UNDEFINED:>{width}s}"
    text = "".join("{:>8s}".format("-") if math.isnan(v) else f"{v:8.4f}" for v in (row.S1, row.S1_conf))
    text += " " + "".join("{:>8s}".format("-") if math.isnan(v) else f"{v:8.4f}" for v in (row.ST, row.ST_conf))
    if shapley:
        text += f"{row.Sh:8.4f}{row.Sh_conf:8.4f}"
    return text


@command("sobol", "Sobol indices of the pose error at one pose, next to the worst-case contributions")
class SobolCommand:
    @staticmethod
    def add_arguments(p):
        add_geometry(p)
        add_budget(p)
        add_pose(p)
        add_sampling(p, default_samples=8192)
        p.add_argument("--replicates", type=positive_int, default=16, metavar="R",
                       help="independent scramblings of the Sobol' points, a power of two (default 16): the "
                            "intervals are Student t intervals over them")
        p.add_argument("--shapley-permutations", type=nonnegative_int, default=None, metavar="M",
                       help="random orders of the Shapley effects (default N / 2; 0: none)")
        p.add_argument("--conf-level", type=probability, default=0.95, metavar="L",
                       help="confidence level of the intervals (default 0.95)")
        p.add_argument("--group", action="append", default=[], metavar="NAME=IN,IN",
                       help="a user group of inputs, e.g. leg_1=rho_1,zeta_1,theta_1,b_1 (repeatable)")
        p.add_argument("--method", choices=("auto", "salib", "vectorised"), default="auto",
                       help="salib: SALib's analyze per output; vectorised: the same estimators for all "
                            "outputs at once (equal to round-off); auto: vectorised (default)")
        p.add_argument("--k-sigma", type=positive_float, default=None, metavar="K",
                       help="bound unbounded (normal) laws as mean ± K·sd for the worst case")
        add_progress(p)
        add_json(p)

    @staticmethod
    def run(args) -> None:
        from ..worstcase.envelope import worst_case
        from ..model.validity import check_linearity
        from ..kinematics.chain import check_poses
        from ..sobol.indices import DEPENDENT_NOTE, sobol_indices
        from ..sobol.ranking import ranking
        from ..model.budget import Budget
        geometry, budget = Geometry.load(args.geometry), Budget.load(args.budget)
        pairs = [_group(text) for text in args.group]
        if len({name for name, _ in pairs}) < len(pairs):
            raise BudgetError(f"--group names a group twice: {', '.join(name for name, _ in pairs)}")
        groups = dict(pairs)
        d = len(budget.factors)
        perms = args.samples // 2 if args.shapley_permutations is None else args.shapley_permutations
        within_limits(args, sobol_estimate(args.samples, 1, d, d + len(budget.groups) + len(groups),
                                           len(OUTPUTS), shapley_permutations=perms))
        check_poses(geometry, args.pose)   # a refused pose before any warning about the analysis
        check_linearity(geometry, budget, args.pose)
        r = sobol_indices(geometry, budget, args.pose, args.samples, rng=args.seed, groups=groups,
                          replicates=args.replicates, conf_level=args.conf_level, method=args.method,
                          shapley_permutations=perms, progress=args.progress)
        wc = worst_case(geometry, budget, args.pose, k_sigma=args.k_sigma)
        tables = {o: ranking(r, wc, o) for o in OUTPUTS}
        if args.json:
            emit_json({
                "outputs": {o: {name: _indices(r, i, k, name) for k, name in enumerate(r.names)}
                            for i, o in enumerate(r.outputs)},
                "ranking": {o: [{key: (_number(v) if isinstance(v, float) else v) for key, v in row.items()
                                 if key != "output"} for row in df.to_dict("records")]
                            for o, df in tables.items()},
                "worst_case": {"position_mm": float(wc.position_mm), "phi_deg": float(wc.phi_deg),
                               "x_mm": float(wc.x_mm), "y_mm": float(wc.y_mm)},
                "groups": {k: list(v) for k, v in r.groups.items()},
                **r.metadata(), "k_sigma": args.k_sigma,
                **provenance(args, geometry, budget, seed=r.seed, n_samples=r.n_samples),
            })
            return
        x, y, phi = args.pose
        shapley = r.Sh is not None
        lines = [f"prp3mc {__version__}  geometry {geometry.name}  budget {budget.name}  "
                 f"pose x={x:g} mm  y={y:g} mm  phi={phi:g} deg",
                 f"Sobol indices: N = {r.n_samples} (x {d + 2 + len(r.groups)} model runs) in {r.replicates} "
                 f"independently scrambled replicates, seed {r.seed}, {100 * r.conf_level:g} % Student t "
                 f"intervals over the replicates, method {r.method}"]
        if shapley:
            lines.append(f"Shapley effects Sh: {r.shapley_permutations} random orders in {r.replicates} batches")
        if r.correlated:
            lines.append(f"Correlated inputs: {DEPENDENT_NOTE}.")
        for o, df in tables.items():
            scale, unit = DISPLAY[o]
            total = wc.value(o) * scale
            key = "Sh" if r.correlated else "ST"
            lines += ["", f"{o}: worst case {float(total):.3f} {unit}; sorted by "
                          + ("Shapley effect Sh" if r.correlated else "total index ST"),
                      f"  {'name':15s}{'S1':>8s}{'± conf':>8s}{'ST':>9s}{'± conf':>8s}"
                      + (f"{'Sh':>8s}{'± conf':>8s}" if shapley else "")
                      + f"{'worst case ' + unit:>18s}{'share':>8s}"]
            for row in df.sort_values(key, ascending=False, kind="stable").itertuples():
                wc_text = (f"{'-':>18s}{'':8s}" if math.isnan(row.worst_case_contribution) else
                           f"{scale * row.worst_case_contribution:18.3f}{100 * row.worst_case_share:7.1f}%")
                lines.append(f"  {row.name:15s}{_index_text(row, shapley, r.constant)}{wc_text}")
        lines += ["", "Worst case: each term's part of the maximum at the maximising vertex. A clearance "
                      "term rho_i cos(zeta_i - omega_i) needs rho_i and zeta_i together, so its part is "
                      "shown on clearance_i ('-' on rho_i and zeta_i)."]
        if budget.effects:
            lines.append(EFFECTS_NOTE)
        if args.k_sigma is not None:
            lines.append(f"Unbounded laws bounded at mean ± {args.k_sigma:g} sd for the worst case.")
        print("\n".join(lines))
