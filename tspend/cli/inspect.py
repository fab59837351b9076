"""``tspend inspect MODEL.xml``: what a compiled MJCF holds, read by the plant domain
whose machine it looks like (``Domain.fits_mjcf``, ``Domain.inspect``), and how it
departs from that domain's ODE."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("inspect", help="read an MJCF model as it is and list how it "
                                              "departs from its domain's ODE")
    p.add_argument("model", help="MJCF file (a path, or a shipped model such as "
                                 "models/double_cartpole.xml)")
    p.add_argument("--slide", default=None, metavar="JOINT",
                   help="the cart's slide joint (default: the only slide joint)")
    p.add_argument("--hinge", default=None, metavar="JOINT",
                   help="the pole's hinge joint (default: the only hinge joint)")
    p.add_argument("--actuator", default=None, metavar="NAME",
                   help="the actuator on the slide joint (default: the only one driving it)")
    from tspend.cli.common import finite

    p.add_argument("--dt", type=finite(), default=None,
                   help="control period to check the timestep against")
    from tspend.cli.common import add_metrics_option

    add_metrics_option(p, "the facts", old="--json")
    return p


def cmd(args: argparse.Namespace) -> int:
    from tspend.cli.common import say
    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    # MuJoCo's warnings: in the error line, or one warning line each; never a log file
    with mujoco_warnings_in_errors(True) as notes:
        status = _cmd(args)
    for note in dict.fromkeys(notes):
        say(f"warning: MuJoCo: {note}")
    return status


def _cmd(args: argparse.Namespace) -> int:
    from tspend.cli.common import check_writable, write_json

    json_path = Path(args.metrics) if args.metrics else None
    if json_path is not None:
        check_writable(json_path, "json")
    from tspend.shipped import given_or_shipped

    model = given_or_shipped(args.model)
    domain = _domain_of(model)
    names = {k: v for k, v in (("slide", args.slide), ("hinge", args.hinge),
                               ("actuator", args.actuator)) if v is not None}
    facts, departures = domain.inspect(model, names=names, dt=args.dt)
    touching = contacts_at_rest(model)
    facts["contacts_at_q0"] = touching or "none"
    if touching:
        departures = [*departures, f"contacts active at the model's initial pose (qpos0): "
                                   f"{', '.join(touching)}: contact forces act from t = 0 "
                                   f"(friction can hold a joint the ODE leaves free)"]
    article = "an" if domain.name[:1] in "aeiou" else "a"
    print(f"{args.model}: {article} {domain.name} model")
    for key, value in facts.items():
        print(f"  {key:<20} {show_value(value)}")
    if departures:
        print(f"departures from the {domain.name} ODE:")
        for line in departures:
            print(f"  - {line}")
    else:
        print(f"no departure from the {domain.name} ODE")
    if json_path is not None:
        write_json(json_path, json.loads(json.dumps({**facts, "departures": departures})))
    return 0


def show_value(value) -> str:
    if isinstance(value, dict):
        return ", ".join(f"{k} {show_value(v)}" for k, v in value.items())
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return "; ".join(value)
    return str(value)


def contacts_at_rest(model: str) -> list[str]:
    """The geom pairs in contact at the model's initial pose ``qpos0``, as
    ``"geom1/geom2"`` (MuJoCo's own collision detection after ``mj_forward``)."""
    import mujoco

    from tspend.runtime.model_file import read_spec

    m = read_spec(model).compile()
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    pairs = []
    for i in range(d.ncon):
        c = d.contact[i]
        a, b = (m.geom(int(g)).name or str(int(g)) for g in c.geom)
        pairs.append(f"{a}/{b}")
    return list(dict.fromkeys(pairs))


def _domain_of(model: str):
    """The domain whose machine the MJCF looks like (ScenarioError: none, unreadable, or
    past the size bounds of docs/reliability.md)."""
    from tspend.runtime.errors import ScenarioError
    from tspend.runtime.model_file import read_spec
    from tspend.plants.registry import DOMAINS

    spec = read_spec(model)
    kinds = tuple(j.type.name.removeprefix("mjJNT_").lower() for j in spec.joints)
    try:
        compiled = spec.compile()
    except ValueError as exc:
        raise ScenarioError(f"{model}: cannot compile MJCF: {exc}") from None
    found = next((d for d in DOMAINS.values() if d.fits_model(compiled)), None)
    if found is None:
        readers = ", ".join(d.name for d in DOMAINS.values() if d.mujoco_kind() is not None)
        raise ScenarioError(f"{model}: no plant domain reads a model with joints "
                            f"({', '.join(kinds) or 'none'}) (domains reading MJCF: {readers})")
    return found
