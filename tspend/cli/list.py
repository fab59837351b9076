"""``tspend list``: every scenario, one name and one description line each."""

from __future__ import annotations

import argparse

from tspend.cli.main import DEFAULT_SCENARIO, EXIT_OK, printable
from tspend.errors import TspendError


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subparsers.add_parser("list", help="list the scenarios with their descriptions")


def cmd(args: argparse.Namespace) -> int:
    from tspend.scenario import available_scenarios, load_scenario

    for path in available_scenarios():
        try:
            desc = load_scenario(path).description
        except TspendError as exc:
            desc = f"(invalid: {exc})"
        mark = " (default)" if path.stem == DEFAULT_SCENARIO else ""
        print(f"{printable(path.stem)}{mark}\n    {printable(' '.join(desc.split()))}")
    return EXIT_OK
