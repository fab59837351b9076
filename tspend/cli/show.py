"""tspend show SCENARIO: the scenario fully resolved, as TOML that runs."""

from __future__ import annotations

import argparse

from tspend.cli.common import DEFAULT_SCENARIO, EXIT_OK, add_scenario_options, load_with_overrides


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "show", help="print a scenario with every key resolved, as TOML that runs",
        description="Print the scenario fully resolved: its own keys with --set, --duration "
                    "and --seed applied, every key it leaves out filled in with the value "
                    "tspend uses, files it names written so they are found from any folder, "
                    "and the machine's numbers as compiled from its model (as comments). "
                    "'tspend show NAME > mine.toml && tspend run mine.toml' runs the same "
                    "experiment as 'tspend run NAME'.")
    p.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO,
                   help=f"a scenario name (tspend list) or a .toml file (default: "
                        f"{DEFAULT_SCENARIO})")
    add_scenario_options(p, recording=False)
    return p


def cmd(args: argparse.Namespace) -> int:
    from tspend.scenario.writer import resolved_toml

    scn = load_with_overrides(args)
    text = resolved_toml(scn)
    print(f"# tspend show {scn.name}: every key resolved (from {scn.path or 'a string'})")
    for line in machine_lines(scn):
        print(f"# {line}")
    print(text, end="")
    return EXIT_OK


def machine_lines(scn) -> list[str]:
    """The machine's numbers as its model compiles (``tspend inspect``'s facts), for a
    MuJoCo scenario; [plant] keys above, where set, are written into that model."""
    from tspend.cli.inspect import show_value
    from tspend.plants.registry import PLANT_KINDS, domain_of, resolve_model_path

    if not PLANT_KINDS[scn.plant.kind].mujoco:
        return []
    path = resolve_model_path(scn)
    names = {key: getattr(scn.plant, field) for key, field in
             (("slide", "slide_joint"), ("hinge", "hinge_joint"), ("actuator", "actuator"))
             if getattr(scn.plant, field, None)}
    try:
        facts, _ = domain_of(scn.plant.kind).inspect(str(path), names=names, dt=None)
    except Exception as exc:  # the run reports a bad model with its own message
        return [f"the model {path.name} could not be read: {exc}"]
    lines = [f"the machine as compiled from {path.name} (tspend inspect):"]
    lines += [f"  {key:<20} {show_value(value)}" for key, value in facts.items()]
    return lines
