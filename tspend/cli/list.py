"""tspend list: every scenario on the search path with its whole description, wrapped to the
terminal's width under its name; --long adds its plant kind, machine, default controller and
duration (tspend show prints every key)."""

from __future__ import annotations

import argparse
import shutil
import textwrap

from tspend.cli.common import DEFAULT_SCENARIO, EXIT_OK, printable
from tspend.runtime.errors import TspendError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "list", help="list the scenarios with their descriptions",
        description="List every scenario found on the search path (--scenario-path, "
                    "$TSPEND_SCENARIO_PATH, ./scenarios, then the shipped ones; the first "
                    "of a name wins), with its description, then the search path itself.")
    p.add_argument("--long", action="store_true",
                   help="add each scenario's plant kind, machine (its model file), default "
                        "controller, duration and file")
    p.add_argument("--files", action="store_true",
                   help="print instead where the shipped files are (models, examples to copy, "
                        "the documents the help text names) and what each example is")
    return p


def facts(scn) -> str:
    """The one line --long adds: kind, machine, controller, duration."""
    from pathlib import Path

    model = getattr(scn.plant, "model", "") or ""
    machine = Path(model).name if model else "(analytic)"
    controller = scn.run.controller or ("first_type" if scn.controller.adaptation == "first"
                                        else "second_type")
    return (f"plant {scn.plant.kind}, machine {machine}, controller {controller}, "
            f"{scn.run.duration:g} s")


def shipped_files() -> list[str]:
    """The lines of ``tspend list --files``: the shipped folders, each example with the
    first line of its docstring (a checkout has them at its top level, a wheel inside the
    package: examples/train_mjx_ppo.py is otherwise hard to find)."""
    import ast

    from tspend.shipped import data_root

    root = data_root()
    lines = [f"shipped with tspend, under {root}:"]
    for folder, what in (("models", "MJCF models (models/third_party/: with their licences)"),
                         ("scenarios", "the scenarios tspend list shows"),
                         ("docs", "the documents; docs/reference/cli.md: every option and "
                                  "exit status"),
                         ("examples", "to copy and run (python FILE --help)")):
        lines.append(f"  {folder + '/':<11} {root / folder}  {what}")
    for example in sorted((root / "examples").glob("*.py")):
        doc = ast.get_docstring(ast.parse(example.read_text(encoding="utf-8"))) or ""
        lines.append(f"    {example.name}: {first_sentence(doc, 90)}")
    return lines


def cmd(args: argparse.Namespace) -> int:
    if args.files:
        print("\n".join(printable(line) for line in shipped_files()))
        return EXIT_OK
    from tspend.scenario import available_scenarios, load_scenario, scenario_dirs
    from tspend.shipped import scenario_search_path

    paths = available_scenarios()
    width = max((len(p.stem) for p in paths), default=0) + len(" (default)")
    columns = max(shutil.get_terminal_size((100, 24)).columns, width + 30)
    for path in paths:
        extra = ""
        try:
            scn = load_scenario(path)
            desc = " ".join(scn.description.split())
            if args.long:
                extra = f"[{facts(scn)}; {path}]"
        except TspendError as exc:
            desc = f"(invalid: {exc})"
        name = path.stem + (" (default)" if path.stem == DEFAULT_SCENARIO else "")
        # break_on_hyphens off: a reader (and a search) sees "time-varying", not "time- varying"
        lines = textwrap.wrap(printable(desc), columns - width - 2,
                              break_on_hyphens=False) or [""]
        if extra:
            lines += textwrap.wrap(printable(extra), columns - width - 2,
                                   break_on_hyphens=False, break_long_words=False)
        print(f"{name:<{width}}  {lines[0]}")
        for line in lines[1:]:
            print(f"{'':<{width}}  {line}")
    found = {d.resolve() for d in scenario_dirs()}
    print("\nsearched, in order (the first scenario of a name wins):")
    for folder in scenario_search_path():
        note = "" if folder.resolve() in found else "  (not there)"
        print(f"  {folder}{note}")
    return EXIT_OK


def first_sentence(text: str, limit: int = 110) -> str:
    """The text up to its first full stop (or ``limit`` characters), on one line."""
    words = " ".join(text.split())
    end = words.find(". ")
    sentence = words if end < 0 else words[:end + 1]
    return sentence if len(sentence) <= limit else sentence[:limit - 3].rstrip() + "..."
