"""Code from outside the package: ``path/to/file.py:Name``, ``package.module:Name`` and
installed entry points.

A user's controller or plant is named on the command line or in Python by a *spec*:

- ``path/to/file.py:Name``: the file is imported as a module of its own (its directory is
  not added to ``sys.path``, so it cannot shadow another module);
- ``package.module:Name``: an importable module (installed, or on ``PYTHONPATH``);
- a bare name registered by an installed package under an entry-point group
  (``tspend.controllers``, ``tspend.plants``; :mod:`importlib.metadata`).

Every failure is a :class:`~tspend.runtime.errors.ScenarioError` (exit 2) of one line naming the
spec and what is wrong.  A module is imported once per process and path (a sweep's worker
loads it once for all its runs).
"""

from __future__ import annotations

import copyreg
import dataclasses
import importlib
import importlib.util
import re
import sys
from functools import lru_cache
from pathlib import Path
from types import ModuleType

from tspend.runtime.errors import ScenarioError

__all__ = ["ENTRY_POINT_GROUPS", "is_spec", "load_object", "entry_point_names", "load_entry_point",
           "own_failure", "failure_text"]

#: the entry-point groups an installed package registers its plug-ins under
ENTRY_POINT_GROUPS = ("tspend.controllers", "tspend.plants")
_MODULE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")


def own_failure(exc: BaseException) -> bool:
    """Whether ``exc``, raised out of a user's code, is that code's own failure (reported as
    such, one line) rather than a stop the command must honour.  Every ``BaseException`` is
    the code's own (``sys.exit``, ``GeneratorExit``, a class of its own), but the CLI's
    :class:`~tspend.runtime.interrupts.Interrupted` (a signal) and a ``KeyboardInterrupt``
    where Python's own SIGINT handler is installed (then it may be a real Ctrl-C; under the
    CLI's handlers a real SIGINT raises ``Interrupted``, so a ``KeyboardInterrupt`` is the
    code's own ``raise``)."""
    import signal

    from tspend.runtime.interrupts import Interrupted

    if isinstance(exc, Interrupted):
        return False
    if isinstance(exc, KeyboardInterrupt):
        return signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    return True


def failure_text(exc: BaseException) -> str:
    """``Type: first line`` of a user code's exception (``SystemExit: 0`` for sys.exit(0))."""
    first = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {first}"


def is_spec(text: str) -> bool:
    """Whether ``text`` names code (``file.py:Name`` or ``module:Name``) rather than a kind."""
    return ":" in text


@lru_cache(maxsize=64)
def _module_from_file(path: str, mtime_ns: int) -> ModuleType:
    name = "tspend_plugin_" + re.sub(r"\W", "_", path)
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ScenarioError(f"{path}: cannot be imported as Python")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses and pickling look their module up by name
    try:
        spec.loader.exec_module(module)
    except ScenarioError:
        raise
    except BaseException as exc:  # the user's code: one line, whatever it raised
        sys.modules.pop(name, None)
        if not own_failure(exc):
            raise
        raise ScenarioError(f"{path}: importing it failed: {failure_text(exc)}") from None
    # a sweep's worker unpickles a scenario holding the file's settings dataclass; the
    # module's name means nothing there, so such objects travel as (path, class, fields)
    for obj in vars(module).values():
        if (isinstance(obj, type) and obj.__module__ == name and dataclasses.is_dataclass(obj)):
            copyreg.pickle(obj, _reduce_by_path)
    return module


def _reduce_by_path(obj: object):
    cls = type(obj)
    path = sys.modules[cls.__module__].__file__
    fields = {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj) if f.init}
    return _rebuild_from_file, (path, cls.__qualname__, fields)


def _rebuild_from_file(path: str, qualname: str, fields: dict) -> object:
    """The inverse of :func:`_reduce_by_path`, in any process."""
    resolved = Path(path)
    obj: object = _module_from_file(str(resolved), resolved.stat().st_mtime_ns)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj(**fields)  # type: ignore[operator]


def _module(where: str, option: str) -> ModuleType:
    if where.endswith(".py") or "/" in where or "\\" in where:
        path = Path(where).expanduser()
        if not path.is_file():
            # examples/custom_controller.py:SaturatedPD works from any folder: the working
            # folder's file first, then the shipped one (tspend.shipped.locate)
            from tspend.shipped import locate

            path = locate(path) or path
        if not path.is_file():
            raise ScenarioError(f"{option} {where}: no such file")
        if path.suffix != ".py":
            raise ScenarioError(f"{option} {where}: expected a .py file")
        resolved = path.resolve()
        return _module_from_file(str(resolved), resolved.stat().st_mtime_ns)
    if not _MODULE.fullmatch(where):
        raise ScenarioError(f"{option} {where}: expected path/to/file.py or package.module")
    try:
        return importlib.import_module(where)
    except ModuleNotFoundError as exc:
        raise ScenarioError(f"{option} {where}: no module named {exc.name!r}") from None
    except BaseException as exc:
        if not own_failure(exc):
            raise
        raise ScenarioError(f"{option} {where}: importing it failed: {failure_text(exc)}") \
            from None


def load_object(spec: str, option: str = "--controller") -> object:
    """The object ``Name`` of ``path/to/file.py:Name`` or ``package.module:Name``.

    ``option`` starts each error message (``--controller x.py:Y: no such file``).
    """
    where, sep, attr = spec.rpartition(":")
    if not sep or not where or not attr:
        raise ScenarioError(f"{option} {spec}: expected path/to/file.py:Class or "
                            f"package.module:Class")
    module = _module(where, option)
    obj = module
    for part in attr.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            public = sorted(n for n in vars(module) if isinstance(vars(module)[n], type)
                            and not n.startswith("_"))
            raise ScenarioError(f"{option} {spec}: {where} has no {attr!r}"
                                + (f"; its classes: {', '.join(public)}" if public else ""))\
                from None
    return obj


def _entry_points(group: str):
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=group)}


def entry_point_names(group: str) -> list[str]:
    """The names installed packages register under ``group``, sorted."""
    return sorted(_entry_points(group))


def load_entry_point(group: str, name: str, option: str = "--controller") -> object | None:
    """The object an installed package registers as ``name`` in ``group`` (None: none does)."""
    ep = _entry_points(group).get(name)
    if ep is None:
        return None
    try:
        return ep.load()
    except BaseException as exc:
        if not own_failure(exc):
            raise
        raise ScenarioError(f"{option} {name}: the entry point {ep.value} ({group}) failed to "
                            f"load: {type(exc).__name__}: {exc}") from None
