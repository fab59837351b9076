"""``tspend list``: every scenario with its whole description, wrapped to the terminal's
width under its name (``tspend inspect`` and the file itself say the rest)."""

from __future__ import annotations

import argparse
import shutil
import textwrap

from tspend.cli.common import DEFAULT_SCENARIO, EXIT_OK, printable
from tspend.errors import TspendError


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subparsers.add_parser("list", help="list the scenarios with their descriptions")


def cmd(args: argparse.Namespace) -> int:
    from tspend.scenario import available_scenarios, load_scenario

    paths = available_scenarios()
    width = max((len(p.stem) for p in paths), default=0) + len(" (default)")
    columns = max(shutil.get_terminal_size((100, 24)).columns, width + 30)
    for path in paths:
        try:
            desc = " ".join(load_scenario(path).description.split())
        except TspendError as exc:
            desc = f"(invalid: {exc})"
        name = path.stem + (" (default)" if path.stem == DEFAULT_SCENARIO else "")
        # break_on_hyphens off: a reader (and a search) sees "time-varying", not "time- varying"
        lines = textwrap.wrap(printable(desc), columns - width - 2,
                              break_on_hyphens=False) or [""]
        print(f"{name:<{width}}  {lines[0]}")
        for line in lines[1:]:
            print(f"{'':<{width}}  {line}")
    return EXIT_OK


def first_sentence(text: str, limit: int = 110) -> str:
    """The text up to its first full stop (or ``limit`` characters), on one line."""
    words = " ".join(text.split())
    end = words.find(". ")
    sentence = words if end < 0 else words[:end + 1]
    return sentence if len(sentence) <= limit else sentence[:limit - 3].rstrip() + "..."
