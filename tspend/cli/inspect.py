"""``tspend inspect MODEL.xml``: what a compiled MJCF cart-pole holds, and how it departs
from the paper's ODE (tspend/plants/mjcf.py)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

#: order of the printed facts
_ROWS = ("cart_mass", "pole_mass", "pole_com", "pole_inertia_pivot", "rod_inertia_pivot",
         "gain_sign", "theta_sign", "gear", "ctrl_range", "force_range", "actuator_type",
         "timestep", "integrator", "contacts", "gravity")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("inspect", help="read an MJCF cart-pole as it is and list how it "
                                              "departs from the paper's ODE")
    p.add_argument("model", help="MJCF file")
    p.add_argument("--slide", default=None, metavar="JOINT",
                   help="the cart's slide joint (default: the only slide joint)")
    p.add_argument("--hinge", default=None, metavar="JOINT",
                   help="the pole's hinge joint (default: the only hinge joint)")
    p.add_argument("--actuator", default=None, metavar="NAME",
                   help="the actuator on the slide joint (default: the only one driving it)")
    from tspend.cli.main import finite

    p.add_argument("--dt", type=finite(), default=None,
                   help="control period to check the timestep against")
    p.add_argument("--json", metavar="PATH", help="write the facts as one JSON object")
    return p


def cmd(args: argparse.Namespace) -> int:
    from tspend.cli.main import say
    from tspend.runtime.native_logs import mujoco_warnings_in_errors

    # MuJoCo's warnings: in the error line, or one warning line each; never a log file
    with mujoco_warnings_in_errors(True) as notes:
        status = _cmd(args)
    for note in dict.fromkeys(notes):
        say(f"warning: MuJoCo: {note}")
    return status


def _cmd(args: argparse.Namespace) -> int:
    from tspend.cli.main import check_writable, write_json
    from tspend.plants.mujoco_plant import MujocoCartPole, guess_names

    json_path = Path(args.json) if args.json else None
    if json_path is not None:
        check_writable(json_path, "json")
    domain = _domain_of(args.model)
    if domain is not None:
        return _inspect_domain(domain, args.model, json_path, write_json)
    slide, hinge, actuator = guess_names(args.model, args.slide, args.hinge, args.actuator)
    plant = MujocoCartPole(args.model, slide_joint=slide, hinge_joint=hinge, actuator=actuator)
    facts = plant.facts
    data = facts.to_json()
    data.update(slide_joint=slide, hinge_joint=hinge, actuator=actuator)
    if args.dt is not None:
        data["departures"] = plant.departures(args.dt)
    print(f"{args.model}: slide '{slide}', hinge '{hinge}', actuator '{actuator}'")
    for key in _ROWS:
        print(f"  {key:<20} {data[key]}")
    for label in ("slide", "hinge"):
        j = data[label]
        print(f"  {label + ' joint':<20} damping {j['damping']:g}, frictionloss "
              f"{j['frictionloss']:g}, armature {j['armature']:g}, stiffness {j['stiffness']:g}, "
              f"limited {j['limited']} {list(j['range']) if j['limited'] else ''}")
    if data["departures"]:
        print("departures from the paper's cart-pole ODE:")
        for line in data["departures"]:
            print(f"  - {line}")
    else:
        print("no departure from the paper's cart-pole ODE")
    if json_path is not None:
        write_json(json_path, json.loads(json.dumps(data)))
    return 0


def _domain_of(model: str):
    """The domain another than the cart-pole whose machine the MJCF looks like, or None
    (the cart-pole's own reading below then runs, with its messages)."""
    import mujoco

    from tspend.plants.registry import DOMAINS

    from tspend.errors import ScenarioError
    from tspend.plants.mjcf import read_spec

    try:
        spec = read_spec(model)
    except ScenarioError:
        return None  # the cart-pole reader reports it
    kinds = tuple(j.type.name.removeprefix("mjJNT_").lower() for j in spec.joints)
    return next((d for d in DOMAINS.values() if d.fits_mjcf(kinds) and d.name != "cartpole"),
                None)


def _inspect_domain(domain, model: str, json_path, write_json) -> int:
    facts, departures = domain.inspect(model)
    print(f"{model}: a {domain.name} model")
    for key, value in facts.items():
        print(f"  {key:<20} {value}")
    if departures:
        print(f"departures from the {domain.name} ODE:")
        for line in departures:
            print(f"  - {line}")
    else:
        print(f"no departure from the {domain.name} ODE")
    if json_path is not None:
        write_json(json_path, json.loads(json.dumps({**facts, "departures": departures})))
    return 0
