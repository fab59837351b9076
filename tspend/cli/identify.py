"""``tspend identify DATA --model MODEL.xml --params KEYS --out fitted.xml``: fit a
machine's physical parameters to a recorded run and write the calibrated MJCF
(docs/identify.md; the method: :mod:`tspend.studies.identify`).

Exit status: 0 fitted and written; 2 bad input (the data, the model, an unidentifiable
set of parameters: one line naming the problem); 3 the fit did not converge (nothing is
written).
"""

from __future__ import annotations

import argparse

from tspend.cli.common import EXIT_OK, bounded_int, finite, plan, say
from tspend.runtime.errors import ScenarioError
from tspend.runtime.bounds import MAX_BOOTSTRAP, MAX_SEED, MIN_SEGMENT_SAMPLES
from tspend.runtime.outputs import OutputRequest, display


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "identify", help="fit a machine's parameters to a recorded run; write the calibrated MJCF",
        description="Fit the named physical parameters of MODEL.xml to a recorded run (tspend's "
                    "export, or any CSV/Parquet whose columns the options map) by multiple "
                    "shooting of the machine's own equations; report each with its 95 % "
                    "interval, the fit and the prediction error on a held-back validation "
                    "segment; write a copy of the MJCF with the fitted values. Exit 2: bad "
                    "data or an unidentifiable set of parameters; exit 3: the fit did not "
                    "converge (nothing is written).")
    p.add_argument("data", metavar="DATA", help="a .csv or .parquet time series")
    p.add_argument("--model", required=True, metavar="MODEL.xml", help="the machine's MJCF")
    p.add_argument("--params", required=True, metavar="KEYS",
                   help="comma-separated parameters to fit, e.g. m,l,M (cart-pole: m, l, M, "
                        "gear, cart_damping, hinge_damping; Furuta: arm_damping, "
                        "pendulum_damping, arm_armature, pendulum_armature, motor_gain, "
                        "back_emf; articulated: the parameter "
                        "vector's names, link1.mass, link1.ipos_z, link1.inertia_2, "
                        "hinge1.damping, motor.gear ...; every model: JOINT.offset, a sensor's "
                        "constant offset); the others keep the model's values")
    p.add_argument("--fix", action="append", default=[], metavar="KEY=VALUE",
                   help="hold a parameter at a known value other than the model's (a calibrated "
                        "gear, say); written into the calibrated MJCF too; repeatable")
    p.add_argument("--out", metavar="PATH.xml", help="the calibrated MJCF to write")
    p.add_argument("--metrics", metavar="PATH.json", help="the fit's figures as JSON")
    p.add_argument("--figure", metavar="PATH.png", help="measured vs predicted on the validation part")
    p.add_argument("--time", metavar="COL", help="time column (default t_s)")
    p.add_argument("--positions", metavar="COL,COL",
                   help="position columns in the model's joint order (default: the export's)")
    p.add_argument("--velocities", metavar="COL,COL", help="velocity columns (with --use-velocities)")
    p.add_argument("--input", metavar="COL", help="the applied input column (default u_N / u_V / u)")
    p.add_argument("--use-velocities", action="store_true",
                   help="fit the measured velocities too (default: positions only; velocities "
                        "are estimated as part of each segment's state)")
    p.add_argument("--validation", type=finite(0.0, 0.9), default=0.25, metavar="SHARE",
                   help="the share of the record held back at its end (default 0.25)")
    p.add_argument("--segment", type=finite(), metavar="S",
                   help="length of each shooting segment, s, at least "
                        f"{MIN_SEGMENT_SAMPLES} samples (default: 2 / the nominal machine's "
                        "fastest unstable eigenvalue, within [50 samples, 2 s])")
    p.add_argument("--uncertainty", choices=("curvature", "bootstrap"), default="curvature",
                   help="the intervals: the fit's Gauss-Newton curvature (default; white noise) "
                        "or a bootstrap over the training segments (resampled with replacement "
                        "and refitted: holds for coloured noise too)")
    p.add_argument("--bootstrap", type=bounded_int(1, MAX_BOOTSTRAP), default=100, metavar="N",
                   help=f"bootstrap replicates (with --uncertainty bootstrap; default 100, at "
                        f"most {MAX_BOOTSTRAP})")
    p.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0,
                   help="seed of the bootstrap's resampling (numpy Generator; default 0)")
    p.add_argument("--jit", action="store_true",
                   help="compile each segment's simulation to C with CasADi's jit (the system's "
                        "cc): a compile of 10-40 s, then ~20x faster evaluations; worth it on "
                        "long records and the articulated machines")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def _cols(text: str | None) -> list[str] | None:
    return None if text is None else [c.strip() for c in text.split(",")]


def cmd(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from tspend.shipped import given_or_shipped

    # as inspect finds it: as given, else the shipped model of that name
    args.model = given_or_shipped(args.model)
    plans = plan([OutputRequest("--out", "calibrated model", ".xml", args.out) if args.out else None,
                  OutputRequest("--metrics", "metrics", ".json", args.metrics) if args.metrics else None,
                  OutputRequest("--figure", "figure", ".png", args.figure) if args.figure else None],
                 [args.data, args.model])
    from tspend.studies import identify as ident
    from tspend.studies.identify_model import load_model

    if args.uncertainty == "bootstrap" and args.bootstrap < 10:
        raise ScenarioError(f"--bootstrap {args.bootstrap}: at least 10 replicates (a 95 % "
                            f"interval from percentiles needs them; 100 or more is better)")
    model = load_model(args.model)
    model.jit = bool(args.jit)
    names = ident.check_names(model, args.params.split(","))
    model.fixed.update(_fixed(args.fix, model, names))
    rec = ident.read_record(args.data, model, time=args.time, positions=_cols(args.positions),
                            velocities=_cols(args.velocities), input=args.input,
                            use_velocities=args.use_velocities)
    if args.segment is not None and args.segment < MIN_SEGMENT_SAMPLES * rec.dt * (1 - 1e-9):
        raise ScenarioError(f"--segment {args.segment:g}: shorter than {MIN_SEGMENT_SAMPLES} "
                            f"samples of the record's {rec.dt:g} s")
    if float(rec.u.std()) == 0.0:
        raise ScenarioError(f"DATA: the input '{rec.columns['input']}' is constant: it excites "
                            f"nothing (record an excitation: tspend excite)")
    ident.identifiability(model, rec, names, segment_s=args.segment, validation=args.validation)
    fit = ident.fit(model, rec, names, segment_s=args.segment, validation=args.validation,
                    use_velocities=args.use_velocities,
                    bootstrap=args.bootstrap if args.uncertainty == "bootstrap" else 0,
                    rng=np.random.default_rng(args.seed))
    targets = {p.request.option: p.target for p in plans}
    figure = None
    if "--figure" in targets:  # drawn before anything is written: a failure replaces nothing
        import io

        buffer = io.BytesIO()
        fit_figure(fit, model, buffer)
        figure = buffer.getvalue()
    print(report(fit, model))
    from tspend.runtime.outputs import write_atomic

    if "--out" in targets:
        changes = model.write({**model.fixed, **fit.values}, targets["--out"])
        print(f"calibrated model: {display(targets['--out'])} ({len(changes)} change(s) named "
              f"in its header comment)")
    if "--metrics" in targets:
        data = {"model": args.model, "data": args.data, "domain": model.domain,
                "columns": rec.columns, **fit.to_json()}
        text = json.dumps(data, indent=2)
        write_atomic(targets["--metrics"], lambda tmp: tmp.write_text(text), what="metrics")
        print(f"metrics: {display(targets['--metrics'])}")
    if "--figure" in targets:
        write_atomic(targets["--figure"], lambda tmp: tmp.write_bytes(figure), what="figure")
        print(f"figure: {display(targets['--figure'])}")
    return EXIT_OK


def _fixed(items, model, names) -> dict:
    import math

    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in model.names:
            raise ScenarioError(f"--fix {item}: KEY=VALUE with KEY one of {', '.join(model.names)}")
        if key in names:
            raise ScenarioError(f"--fix {key}: it is also in --params (fit it or fix it)")
        try:
            value = float(text)
        except ValueError:
            raise ScenarioError(f"--fix {item}: not a number: {text!r}") from None
        if not math.isfinite(value):
            raise ScenarioError(f"--fix {item}: must be finite")
        problem = physical_problem(key, value)
        if problem:
            raise ScenarioError(f"--fix {key}={text.strip()[:40]}: {problem} "
                                f"({model.meaning.get(key, key)})")
        out[key] = value
    return out


def physical_problem(key: str, value: float) -> str:
    """What no machine can have ("" when none): a negative mass, inertia, armature or
    damping, a zero gear or gain (the input would move nothing)."""
    leaf = key.rsplit(".", 1)[-1]
    if (leaf in ("m", "M", "mass") or leaf.startswith("inertia") or "damping" in leaf
            or "armature" in leaf) and value < 0:
        return "must be >= 0"
    if ("gear" in leaf or "gain" in leaf) and value == 0:
        return "must not be 0: the input would move nothing"
    return ""


def report(fit, model) -> str:
    lines = [f"{model.domain} ({model.path}): {len(fit.names)} parameter(s) from "
             f"{fit.train_s:.3g} s in {fit.segments} segments of {fit.segment_s:g} s; "
             f"validation {fit.validation_s:.3g} s",
             f"  {'parameter':<18}{'nominal':>12}{'fitted':>14}{'std':>12}   95 % interval"
             + ("  (bootstrap percentiles; curvature std)" if fit.uncertainty == "bootstrap" else "")]
    for n in fit.names:
        lo, hi = fit.interval(n)
        lines.append(f"  {n:<18}{fit.nominal[n]:>12.6g}{fit.values[n]:>14.7g}{fit.std[n]:>12.3g}"
                     f"   [{lo:.7g}, {hi:.7g}]"
                     + (f"  {fit.std_curvature[n]:.3g}" if fit.uncertainty == "bootstrap" else ""))
    lines.append("  channel      noise std    rms fit    rms validation (fitted / nominal)")
    for c in fit.rms_fit:
        lines.append(f"  {c:<12}{fit.noise_std[c]:>10.3g}{fit.rms_fit[c]:>11.3g}"
                     f"    {fit.rms_validation.get(c, float('nan')):.3g} / "
                     f"{fit.rms_validation_nominal.get(c, float('nan')):.3g}")
    lines.append(f"  solver: {fit.status} ({fit.iterations} evaluations)")
    if fit.uncertainty == "bootstrap":
        lines.append(f"  uncertainty: bootstrap, {fit.replicates.shape[0]} refits on the "
                     f"{fit.segments} training segments resampled with replacement")
    return "\n".join(lines)


def fit_figure(fit, model, path) -> None:
    """Measured vs predicted (fitted and nominal) on the validation windows, per position."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = fit.validation_trace
    if not tr:
        raise ScenarioError("--figure: no validation windows to draw (--validation 0?)")
    dof = model.dof
    fig, axes = plt.subplots(dof, 1, figsize=(9, 2.6 * dof), sharex=True, squeeze=False)
    axes = axes[:, 0]  # one hinge: still a column of one
    head = tr["head"]
    for c in range(dof):
        ax = axes[c]
        for j in range(tr["t"].shape[0]):
            t = tr["t"][j]
            ax.plot(t, tr["measured"][j, c], color="0.2", lw=1.0, label="measured" if j == 0 else None)
            ax.plot(t[head:], tr["predicted_nominal"][j, c, head:], color="tab:red", lw=1.0,
                    ls="--", label="nominal model" if j == 0 else None)
            ax.plot(t[head:], tr["predicted"][j, c, head:], color="tab:blue", lw=1.2,
                    label="identified model" if j == 0 else None)
            ax.axvline(t[0], color="0.8", lw=0.6)
        ax.set_ylabel(f"{model.state_names[c]}")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[0].set_title("validation: each window's state from its first samples, then free-run prediction")
    axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=110)
    plt.close(fig)
