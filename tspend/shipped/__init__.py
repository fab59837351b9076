"""Where the shipped models, policies, scenarios and plans are.

The repository keeps them at its top level (``models/``, ``models/policies/``,
``scenarios/``, ``scenarios/plans/``, ``examples/``), where users and the documents expect them. The
wheel ships the same folders inside this package (pyproject.toml maps the data packages
``tspend.shipped.models`` and ``tspend.shipped.scenarios`` onto them), so an installed
tspend finds them through :mod:`importlib.resources` from any working folder; a source
checkout (editable install, or the tree on ``PYTHONPATH``) finds them beside the package.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path
from typing import Any

__all__ = ["data_root", "scenario_search_path", "locate", "given_or_shipped", "find_named_file",
           "SCENARIO_PATH_VARIABLE"]

#: the environment variable that names a user's own folders of scenarios (os.pathsep
#: separated), searched before ./scenarios and the shipped ones; ``tspend --scenario-path``
#: prepends to it
SCENARIO_PATH_VARIABLE = "TSPEND_SCENARIO_PATH"


def data_root() -> Path:
    """The folder holding the shipped ``models/`` and ``scenarios/``: inside the installed
    package when tspend came from its wheel, else the source checkout's top level."""
    inside = Path(str(files(__name__)))
    if (inside / "scenarios").is_dir():
        return inside
    return Path(__file__).resolve().parents[2]


def scenario_search_path() -> list[Path]:
    """The folders searched for a scenario by name, first match wins: the folders of
    ``TSPEND_SCENARIO_PATH`` (as given), ``./scenarios``, then the shipped scenarios."""
    given = [Path(p) for p in os.environ.get(SCENARIO_PATH_VARIABLE, "").split(os.pathsep) if p]
    return [*given, Path.cwd() / "scenarios", data_root() / "scenarios"]


def locate(path: str | os.PathLike, scenario_path: str = "") -> Path | None:
    """The file a scenario names (its MJCF, a policy, a plan), or None: ``path`` as given
    when absolute; else relative to the scenario file's folder, then the working folder,
    then the shipped data (so ``models/cartpole.xml`` in a shipped scenario, or in one a
    user wrote with ``tspend show``, is the shipped model wherever tspend runs)."""
    p = Path(path)
    if p.is_absolute():
        return p if p.is_file() else None
    bases = []
    if scenario_path and scenario_path != "<string>":
        bases.append(Path(scenario_path).resolve().parent)
    bases += [Path.cwd(), data_root()]
    return next((b / p for b in bases if (b / p).is_file()), None)


def given_or_shipped(path: str) -> str:
    """A file a user names on the command line (``inspect MODEL.xml``, ``identify --model``):
    as given when it is there, else the shipped file of that name (``models/cartpole.xml``
    from any folder, as a scenario finds it: :func:`locate`), else as given, so the
    command's own check says "no such file" of what the user typed."""
    return str(locate(path) or path)


def find_named_file(path: str, scenario: Any, key: str) -> Path:
    """The file a scenario's setting ``key`` names (a policy, a plan), looked for like a
    scenario's MJCF (:func:`locate`; ScenarioError naming ``key`` if none)."""
    from tspend.runtime.errors import ScenarioError

    found = locate(path, scenario.path)
    if found is not None:
        return found
    raise ScenarioError(f"{scenario.path or scenario.name}: {key} = {path!r}: no such file")
