"""Optional packages: a missing one is one line naming the extra that installs it.

:func:`missing_extra` is the one check (``importlib.util.find_spec``: nothing is imported);
:func:`require` raises it as an ImportError, for the modules of tspend that need an extra
(``tspend.gym`` needs gymnasium). The core dependencies (python-control, matplotlib, CasADi)
are listed too: an environment built without them (an old install, a distribution's
package) gets the same one line.
"""

from __future__ import annotations

import importlib.util

__all__ = ["EXTRAS", "CORE_PIP", "missing_extra", "require"]

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


def require(module: str, user: str) -> None:
    """Raise ImportError, one line naming the extra, when ``module`` cannot be imported."""
    problem = missing_extra(module, user)
    if problem:
        raise ImportError(problem, name=module)
