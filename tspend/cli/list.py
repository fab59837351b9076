"""``tspend list``: every scenario, one line each: its name and its description's first
sentence (``tspend inspect`` and the file itself say the rest)."""

from __future__ import annotations

import argparse

from tspend.cli.main import DEFAULT_SCENARIO, EXIT_OK, printable
from tspend.errors import TspendError


def add_parser(subparsers) -> argparse.ArgumentParser:
    return subparsers.add_parser("list", help="list the scenarios with their descriptions")


def cmd(args: argparse.Namespace) -> int:
    from tspend.scenario import available_scenarios, load_scenario

    paths = available_scenarios()
    width = max((len(p.stem) for p in paths), default=0) + len(" (default)")
    for path in paths:
        try:
            desc = first_sentence(load_scenario(path).description)
        except TspendError as exc:
            desc = f"(invalid: {exc})"
        name = path.stem + (" (default)" if path.stem == DEFAULT_SCENARIO else "")
        print(printable(f"{name:<{width}}  {desc}"))
    return EXIT_OK


def first_sentence(text: str, limit: int = 110) -> str:
    """The text up to its first full stop (or ``limit`` characters), on one line."""
    words = " ".join(text.split())
    end = words.find(". ")
    sentence = words if end < 0 else words[:end + 1]
    return sentence if len(sentence) <= limit else sentence[:limit - 3].rstrip() + "..."
