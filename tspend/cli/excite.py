"""``tspend excite SCENARIO --out exp.toml``: write an identification experiment.

The scenario written is SCENARIO with its controller replaced by the ``excited`` kind
(:mod:`tspend.controllers.excitation`): a stabilising controller (``--inner``, default
``lqr``) plus a multisine, chirp or PRBS (``--signal``) added to its command and clipped
to the actuator's range; the reference is held at the operating point and the injected
disturbance removed (an experiment's input is the excitation alone).  Unless
``--amplitude`` is given, the amplitude is sized by one trial run of the nominal machine
(the closed loop is near linear at these amplitudes, so the motion scales with it): the
largest that keeps every bounded state (the task's bounds, the rail) within ``--share``
of its bound and the command within the actuator's range.  ``tspend run exp.toml`` then
gives a recording and ``tspend export`` the table ``tspend identify`` reads.
"""

from __future__ import annotations

import argparse
import json
import math

from tspend.cli.common import EXIT_OK, finite, plan
from tspend.runtime.errors import ScenarioError
from tspend.runtime.outputs import OutputRequest, display


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("excite", help="write an identification experiment (a scenario) for a machine",
                       description=__doc__.split("\n\n")[1].replace("\n", " "))
    p.add_argument("scenario", metavar="SCENARIO", help="a scenario name or .toml path")
    p.add_argument("--out", required=True, metavar="PATH.toml", help="the experiment to write")
    p.add_argument("--signal", choices=("multisine", "chirp", "prbs"), default="multisine",
                   help="the excitation added to the stabilising command: a multisine (default), "
                        "a chirp or a pseudo-random binary sequence")
    p.add_argument("--inner", default="lqr", metavar="KIND",
                   help="the stabilising controller the excitation is added to (default lqr)")
    p.add_argument("--amplitude", type=finite(), metavar="U",
                   help="peak of the excitation in u's units (default: sized by a trial run)")
    p.add_argument("--share", type=finite(0.0, 1.0), default=0.3,
                   help="the share of each bound the trial run's motion may reach (default 0.3)")
    p.add_argument("--f-min", type=finite(), default=0.1, metavar="HZ", help="default 0.1 Hz")
    p.add_argument("--f-max", type=finite(), default=3.0, metavar="HZ", help="default 3 Hz")
    p.add_argument("--duration", type=finite(), metavar="S", help="the run's length (default: the scenario's)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    return p


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else ("nan" if v != v else repr(v))
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise ScenarioError(f"cannot write {type(v).__name__} into TOML")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def dump_toml(data: dict, prefix: str = "") -> str:
    """A scenario dict as TOML: scalars and arrays first, then sub-tables."""
    lines, tables = [], []
    for k, v in data.items():
        (tables if isinstance(v, dict) else lines).append((k, v))
    out = [f"{_key(k)} = {_toml_value(v)}" for k, v in lines]
    for k, v in tables:
        name = f"{prefix}.{_key(k)}" if prefix else _key(k)
        body = dump_toml(v, name)
        out.append(f"\n[{name}]\n{body}" if any(not isinstance(x, dict) for x in v.values()) or not v
                   else f"\n{body}")
    return "\n".join(out).strip("\n") + "\n"


def cmd(args: argparse.Namespace) -> int:
    import tomllib
    from pathlib import Path

    from tspend.scenario import find_scenario, load_scenario, resolve_model_path

    src = find_scenario(args.scenario)
    plans = plan([OutputRequest("--out", "experiment", ".toml", args.out)], [str(src)])
    scn = load_scenario(src)
    from tspend.controllers import load as load_kind

    load_kind(args.inner, "--inner")
    if args.f_max <= args.f_min:
        raise ScenarioError(f"--f-max {args.f_max:g}: must exceed --f-min ({args.f_min:g})")
    from tspend.controllers.excitation import MAX_BAND_RATIO, nyquist_hz

    if args.f_max > MAX_BAND_RATIO * args.f_min:
        raise ScenarioError(f"--f-max {args.f_max:g}: at most {MAX_BAND_RATIO:g} times --f-min "
                            f"({args.f_min:g})")
    if args.f_max > nyquist_hz(scn):
        raise ScenarioError(f"--f-max {args.f_max:g}: above {nyquist_hz(scn):g} Hz, half the "
                            f"rate {scn.name} applies its input at")
    data = tomllib.loads(Path(src).read_text(encoding="utf-8"))
    plant = data.setdefault("plant", {})
    if "model" in plant:
        plant["model"] = str(resolve_model_path(scn))
    run = data.setdefault("run", {})
    run["controller"] = "excited"
    if args.duration is not None:
        run["duration"] = args.duration
    data["reference"] = {"kind": "constant", "value": 0.0}
    data["disturbance"] = {"kind": "zero"}
    from tspend.controllers.full_model import full_model
    from tspend.loop.simulation import nominal_machine

    try:
        fm = full_model(scn, nominal_machine(scn))
        u_lo, u_hi = fm.u_lo, fm.u_hi
    except ScenarioError:
        u_lo, u_hi = -math.inf, math.inf
    exc = {"inner": args.inner, "signal": args.signal, "f_min_hz": args.f_min,
           "f_max_hz": args.f_max, "amplitude": 1.0}
    # an unbounded actuator's range is left out (the kind's default: no clip)
    exc.update({k: v for k, v in (("u_lo", u_lo), ("u_hi", u_hi)) if math.isfinite(v)})
    data.setdefault("controllers", {})["excited"] = exc
    data["description"] = (f"Identification experiment on {Path(src).stem}: {args.signal} "
                           f"{args.f_min:g}-{args.f_max:g} Hz added to {args.inner}'s command "
                           f"(tspend excite; docs/identify.md)")
    if args.amplitude is not None:
        exc["amplitude"] = args.amplitude
        note = "given"
    else:
        exc["amplitude"], note = _size(data, src, args.share, u_lo, u_hi)
    text = dump_toml(data)
    target = plans[0].target
    import os
    import tempfile

    # the experiment must load as a scenario before it is written: checked from a file
    # beside the target (its relative paths are the target's), created exclusively under a
    # fresh hidden name, so no file of the user's is touched
    fd, name = tempfile.mkstemp(prefix=f".{Path(target).name[:100]}.", suffix=".check.toml",
                                dir=Path(target).parent)
    tmp_check = Path(name)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        try:
            load_scenario(tmp_check)
        except ScenarioError as exc:
            raise ScenarioError(str(exc).replace(str(tmp_check), f"the experiment for {target}")
                                ) from None
    finally:
        tmp_check.unlink(missing_ok=True)
    from tspend.runtime.outputs import write_atomic

    write_atomic(target, lambda tmp: tmp.write_text(text, encoding="utf-8"), what="experiment")
    print(f"experiment: {display(target)} ({args.signal} {args.f_min:g}-{args.f_max:g} Hz, "
          f"amplitude {exc['amplitude']:.4g} ({note}) on {args.inner}; run it with "
          f"'tspend run {display(target)}')")
    return EXIT_OK


def _size(data: dict, src, share: float, u_lo: float, u_hi: float) -> tuple[float, str]:
    """The amplitude that keeps the trial run's motion within ``share`` of every bound."""
    import tempfile
    from pathlib import Path

    import numpy as np

    import tspend
    from tspend.task import build_task

    import copy

    trial = 1.0
    # the nominal machine from rest: the motion the excitation alone causes
    quiet = copy.deepcopy(data)
    quiet.pop("randomize", None)
    if "x0" in quiet.get("plant", {}):
        quiet["plant"]["x0"] = [0.0] * len(quiet["plant"]["x0"])
    with tempfile.TemporaryDirectory(prefix="tspend-excite-") as d:
        path = Path(d) / "trial.toml"
        path.write_text(dump_toml(quiet), encoding="utf-8")
        try:
            r = tspend.run(path, keep_history=True)
            task = build_task(r.plant, r.scenario.task, r.scenario.effects, where=str(path))
        except ScenarioError as exc:  # named by the user's scenario, not the trial's file
            raise ScenarioError(str(exc).replace(str(path), f"{src} (the trial run)")) from None
    if "state" not in r.history or not len(r.history["state"]):
        raise ScenarioError(f"{src}: the trial run at amplitude {trial:g} ended '{r.status}' "
                            f"at its first sample ({r.end.message[:200]}); give --amplitude")
    state = np.asarray(r.history["state"])
    u = np.asarray(r.history["u"]).ravel()
    if r.status not in ("completed",):
        raise ScenarioError(f"{src}: the trial run at amplitude {trial:g} ended '{r.status}'; "
                            f"give --amplitude")
    ratios = []
    for b in task.bounds():
        peak = float(np.max(np.abs(state[:, b.index])))
        half = min(abs(b.lo), abs(b.hi))
        if math.isfinite(half) and peak > 0:
            ratios.append(share * half / peak)
    rail = r.scenario.effects.rail
    names = tuple(getattr(r.plant, "state_names", ()))
    if rail > 0 and names:
        peak = float(np.max(np.abs(state[:, 0])))
        ratios.append(share * rail / max(peak, 1e-12))
    peak_u = float(np.max(np.abs(u)))
    if math.isfinite(u_hi) and math.isfinite(u_lo):
        ratios.append(share * min(abs(u_lo), abs(u_hi)) / max(peak_u, 1e-12))
    if not ratios:
        return trial, "no bound to size it by"
    return trial * min(ratios), f"sized to {share:g} of the bounds"
