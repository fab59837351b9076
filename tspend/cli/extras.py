"""Optional packages a command needs, checked before any work: a missing one is one line
naming the extra that installs it (exit 2), never an internal error after minutes of work.

:func:`missing_extra` is the one check (``importlib.util.find_spec``: nothing is imported);
:func:`needed` says what a parsed command line needs.  The core dependencies (python-control,
matplotlib, CasADi, sympy) are listed too: an environment built without them (an old
install, a distribution's package) gets the same one line.
"""

from __future__ import annotations

import argparse
import importlib.util

from tspend.errors import ScenarioError

__all__ = ["EXTRAS", "missing_extra", "needed", "check_needed"]

#: module -> (what it is, the extra that installs it; None: a core dependency)
EXTRAS = {
    "optuna": ("Optuna", "tune"),
    "dask.distributed": ("dask.distributed", "dask"),
    "gymnasium": ("gymnasium", "gym"),
    "onnxruntime": ("onnxruntime", "rl"),
    # core dependencies: missing only from an environment built without them
    "matplotlib": ("matplotlib", None),
    "control": ("python-control", None),
    "casadi": ("CasADi", None),
}
#: the pip name of a core dependency
CORE_PIP = {"matplotlib": "matplotlib", "control": "control", "casadi": "casadi"}

#: controller kinds -> the module they need
KIND_NEEDS = {"policy": "onnxruntime", "mpc": "casadi", "lqr": "control", "swingup": "control"}


def _present(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a parent package missing, or a broken entry
        return False


def missing_extra(module: str, user: str) -> str | None:
    """None when ``module`` can be imported, else the one line: ``user`` needs it and
    ``pip install 'tspend[extra]'`` installs it."""
    if _present(module):
        return None
    what, extra = EXTRAS[module]
    if extra is None:
        return (f"{user} needs {what}, a dependency of tspend missing from this environment: "
                f"pip install {CORE_PIP[module]} (or reinstall tspend)")
    return f"{user} needs {what}, an optional extra: pip install 'tspend[{extra}]'"


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
