"""Optional packages a command needs, checked before any work: a missing one is one line
naming the extra that installs it (exit 2), never an internal error after minutes of work.

:func:`tspend.runtime.extras.missing_extra` is the one check; :func:`needed` says what a
parsed command line needs.
"""

from __future__ import annotations

import argparse

from tspend.runtime.errors import ScenarioError
from tspend.runtime.extras import EXTRAS, missing_extra

__all__ = ["EXTRAS", "KIND_NEEDS", "missing_extra", "needed", "check_needed"]

#: controller kinds -> the module they need
KIND_NEEDS = {"policy": "onnxruntime", "mpc": "casadi", "lqr": "control", "swingup": "control"}


def needed(args: argparse.Namespace) -> list[tuple[str, str]]:
    """``(module, who needs it)`` for a parsed command line."""
    command = getattr(args, "command", "")
    out: list[tuple[str, str]] = []
    if command == "tune":
        out.append(("optuna", "tspend tune"))
    if command == "compare" and getattr(args, "tune", None) is not None:
        out.append(("optuna", "tspend compare --tune"))
    if getattr(args, "dask", None) is not None:
        out.append(("dask.distributed", f"tspend {command} --dask"))
    if command == "figures":
        out.append(("matplotlib", f"tspend figures {getattr(args, 'figure', '')}".rstrip()))
    controllers = getattr(args, "controller", None)
    if isinstance(controllers, str):
        for kind in (k.strip() for k in controllers.split(",")):
            if kind in KIND_NEEDS:
                out.append((KIND_NEEDS[kind], f"controller '{kind}'"))
    return out


def check_needed(args: argparse.Namespace) -> None:
    """Raise ScenarioError (exit 2) naming the extra of the first missing package."""
    for module, user in needed(args):
        problem = missing_extra(module, user)
        if problem:
            raise ScenarioError(problem)
