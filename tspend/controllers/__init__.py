"""Controllers behind one protocol (:mod:`tspend.controllers.base`), chosen by kind.

:data:`KINDS` is the one registry of controller kinds: kind -> its class.  The class
carries everything the kind is: its settings dataclass (``Settings``, read from the
scenario's ``[controllers.KIND]`` table, :mod:`.settings`; the paper's kinds read
``[controller]``), what it needs of a plant's domain (``needs``), the domains it is made
for (``domains``), what it guarantees, and how it is built
(``Class.from_scenario(scenario, machine)``, the nominal machine the runner built:
:func:`tspend.loop.simulation.nominal_machine`).  The kinds: the paper's ``second_type``
(the default) and ``first_type`` (antecedents fixed), and the baselines to compare them
with, one module each (``pd``, ``lqr``, ``feedback_linearization``, ``sliding_mode``,
``wang_indirect``, ...; see docs/controllers.md).

A controller of one's own is named like a kind, by a spec (:func:`resolve`):
``path/to/file.py:Class``, ``package.module:Class``, or the name an installed package
registers under the entry-point group ``tspend.controllers``.  ``Class`` is a
:class:`Controller` built as ``Class(scenario, settings)`` when it declares a ``Settings``
dataclass (read from ``[controllers.<Class.kind>]``, see :mod:`.settings`), else as
``Class(scenario)`` (:meth:`Controller.from_scenario`); a function
``f(scenario) -> Controller`` works too.  ``examples/custom_controller.py`` and
docs/writing-a-controller.md show one.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable

from tspend.controllers import feedback_linearization, lqr, pd, sliding_mode, swingup, wang_indirect
from tspend.controllers import mpc
from tspend.controllers import tvlqr
from tspend.controllers import policy
from tspend.controllers import excitation
from tspend.controllers import mpsc, safety
from tspend.controllers.base import Controller, Diagnostic
from tspend.controllers.paper.controller import AdaptiveFuzzyController, FirstTypeController
from tspend.controllers.settings import KindSettings
from tspend.runtime.errors import ScenarioError
from tspend.runtime import plugins

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.controllers.settings import Search
    from tspend.plants.base import Plant


#: controller kind -> its class (what it declares: ``Settings``, ``needs``, ``domains``,
#: ``guarantees``; how it is built: ``from_scenario``), in the order kinds are listed
KINDS: dict[str, type[Controller]] = {cls.kind: cls for cls in (
    AdaptiveFuzzyController, FirstTypeController, pd.PDController, lqr.LQRController,
    feedback_linearization.FeedbackLinearizationController,
    sliding_mode.SlidingModeController, wang_indirect.WangIndirectController,
    swingup.SwingUpController, mpc.MPCController, tvlqr.TVLQRController,
    policy.PolicyController, excitation.ExcitedController)}


@dataclass(frozen=True)
class SafetyFilterKind:
    """A safety filter ``[safety] filter`` names: its class (whose ``FILTER`` is the name)
    and ``wrap(scenario, controller, machine)``, which puts it around a controller."""

    cls: type[safety.SafetyFilter]
    wrap: Callable[..., safety.SafetyFilter]


#: safety filter name -> the filter, the one registry of safety filters (docs/safety.md);
#: ``[safety] filter`` takes "off" or one of these names
SAFETY_FILTERS: dict[str, SafetyFilterKind] = {f.cls.FILTER: f for f in (
    SafetyFilterKind(safety.SafetyFilter, safety.wrap),
    SafetyFilterKind(mpsc.PredictiveSafetyFilter, mpsc.wrap))}
#: what ``[safety] filter`` and ``--safety`` accept
SAFETY_CHOICES = ("off", *SAFETY_FILTERS)


def _table_settings(cls: type[Controller]) -> type | None:
    """The kind's settings class when it is read from ``[controllers.KIND]`` (the paper's
    ``[controller]`` is read by the scenario reader itself)."""
    st = cls.Settings
    return st if st is not None and issubclass(st, KindSettings) else None


#: the entry-point group of installed controller packages (``name = "module:Class"``)
ENTRY_POINT_GROUP = "tspend.controllers"

_PAPER_SUMMARY = {
    "second_type": "the paper's controller: T-S consequents and B-spline membership "
                   "functions adapt on-line (settings: [controller])",
    "first_type": "the paper's controller with the membership functions fixed: consequents "
                  "adapt (settings: [controller])",
}


@dataclass(frozen=True)
class Kind:
    """A controller kind, built in or a plug-in, as :func:`resolve` finds it."""

    name: str                                  # what ``controller.kind`` records
    #: (scenario, nominal machine or None) -> a controller, not reset
    build: Callable[..., Controller]
    settings: type | None                      # its [controllers.NAME] dataclass, if any
    summary: str                               # one line for ``--controller help``
    source: str = ""                           # the spec it came from ("" if built in)
    cls: type[Controller] = Controller         # what it declares (a function: nothing)


def _summary(kind: str) -> str:
    if kind in _PAPER_SUMMARY:
        return _PAPER_SUMMARY[kind]
    doc = (sys.modules[KINDS[kind].__module__].__doc__ or "").strip().splitlines()
    return doc[0].split(": ", 1)[-1].rstrip(".") if doc else ""


def _plugin_kind(obj: object, spec: str, option: str) -> Kind:
    """The :class:`Kind` of a user's class or factory function."""
    if isinstance(obj, type):
        if not issubclass(obj, Controller):
            raise ScenarioError(f"{option} {spec}: {obj.__name__} is not a Controller (subclass "
                                f"tspend.controllers.base.Controller; see "
                                f"docs/writing-a-controller.md)")
        name = obj.kind or obj.__name__
        settings = getattr(obj, "Settings", None)  # optional: a plug-in's own attribute
        if settings is not None and not (dataclasses.is_dataclass(settings)
                                         and issubclass(settings, KindSettings)):
            raise ScenarioError(f"{option} {spec}: {obj.__name__}.Settings must be a dataclass "
                                f"subclassing tspend.controllers.settings.KindSettings")
        doc = (obj.__doc__ or "").strip().splitlines()
        build = obj.from_scenario
    elif callable(obj):
        name = getattr(obj, "kind", None) or getattr(obj, "__name__", "plugin")
        settings = getattr(obj, "Settings", None)
        doc = (getattr(obj, "__doc__", None) or "").strip().splitlines()
        factory = obj

        def build(scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
            return factory(scenario)  # a user's factory takes the scenario alone
    else:
        raise ScenarioError(f"{option} {spec}: is a {type(obj).__name__}, not a Controller "
                            f"class or a function returning one")
    if name in KINDS:
        raise ScenarioError(f"{option} {spec}: its kind {name!r} is a built-in kind's name; "
                            f"give the class another 'kind'")
    return Kind(name, build, settings, doc[0] if doc else "", spec,
                obj if isinstance(obj, type) else Controller)


def resolve(spec: str, option: str = "--controller") -> Kind:
    """The kind ``spec`` names: a built-in kind, ``path/to/file.py:Class``,
    ``package.module:Class`` or an installed ``tspend.controllers`` entry point.

    Raises ScenarioError (one line) for anything else.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ScenarioError(f"{option}: expected a controller kind or a plug-in spec "
                            f"(file.py:Class), got {spec!r:.80}")
    if spec in _OBJECTS:  # a class or an instance handed to tspend.run (python_object_spec)
        return _OBJECTS[spec]
    if spec in KINDS:
        cls = KINDS[spec]
        return Kind(spec, cls.from_scenario, _table_settings(cls), _summary(spec), "", cls)
    if spec.endswith(safety.SUFFIX) and len(spec) > len(safety.SUFFIX):
        # ``pd+cbf``: the kind behind the safety filter (docs/safety.md)
        base = resolve(spec[:-len(safety.SUFFIX)], option)

        def filtered(scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
            ctrl = base.build(scenario, machine)
            return ctrl if isinstance(ctrl, safety.SafetyFilter) else safety.wrap(scenario, ctrl, machine)

        return replace(base, name=base.name + safety.SUFFIX, build=filtered,
                       summary=f"{base.summary} (behind the CBF safety filter)")
    if plugins.is_spec(spec):
        return _plugin_kind(plugins.load_object(spec, option), spec, option)
    obj = plugins.load_entry_point(ENTRY_POINT_GROUP, spec, option)
    if obj is not None:
        return _plugin_kind(obj, spec, option)
    installed = plugins.entry_point_names(ENTRY_POINT_GROUP)
    raise ScenarioError(f"{option} {spec}: unknown kind; allowed: {', '.join([*KINDS, *installed])}"
                        f", or path/to/file.py:Class, or package.module:Class "
                        f"('--controller help' lists them)")


#: classes and instances handed to tspend.run, by the spec they were given (this process only)
_OBJECTS: dict[str, Kind] = {}


def python_object_spec(obj: object, option: str = "controller") -> str:
    """A spec string for a controller class (or factory) or a controller instance given
    from Python (``tspend.run(..., controller=MyController)``), so every path that takes a
    spec takes it.  An importable class gets ``module:Class``; any other object a name of
    its own in this process (``python:MyController``)."""
    if isinstance(obj, Controller):
        instance = obj
        kind = _plugin_kind(type(obj), f"python:{type(obj).__qualname__}", option)

        def build(scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
            return instance

        kind = dataclasses.replace(kind, build=build)
    elif isinstance(obj, type) or callable(obj):
        name = getattr(obj, "__qualname__", getattr(obj, "__name__", "plugin"))
        kind = _plugin_kind(obj, f"python:{name}", option)
    else:
        raise ScenarioError(f"{option}: expected a kind, a plug-in spec, a Controller class or "
                            f"instance, got {obj!r:.80}")
    spec = f"python:{kind.name}"
    if spec in _OBJECTS and _OBJECTS[spec].build is not kind.build:
        spec = f"python:{kind.name}@{id(obj):x}"  # two objects of one name: both kept apart
    _OBJECTS[spec] = dataclasses.replace(kind, source=spec)
    return spec


def kind_class(name: str) -> type[Controller]:
    """The controller class of the built-in kind ``name`` (KeyError for another)."""
    return KINDS[name]


def needs_machine(scenario: "Scenario", kind: str | None = None) -> bool:
    """Whether building the kind ``kind`` (any spec :func:`build` takes; None: the
    scenario's own) for ``scenario`` designs on a model of the plant, so the runner must
    hand it the nominal machine: a built-in kind that needs a model of the plant's domain,
    the ``excited`` kind around one, and any kind behind the safety filter."""
    if kind is None:
        kind = scenario.run.controller or None
    if scenario.safety.filter in SAFETY_FILTERS or (kind or "").endswith(safety.SUFFIX):
        return True
    cls = KINDS.get(kind or "")
    if cls is excitation.ExcitedController:
        from tspend.controllers.settings import settings_for

        return needs_machine(scenario, settings_for(scenario, excitation.ExcitationSettings).inner)
    return cls is not None and bool(cls.needs)


def unsupported(scenario: "Scenario", kind: str, cls: type[Controller] | None = None) -> str | None:
    """Why the kind ``kind`` (of class ``cls``, default the built-in kind's) cannot run on
    the scenario's plant, as the one line a user sees (None: it can), from what the kind
    declares (``needs``, ``domains``) and what the plant's domain provides
    (:attr:`tspend.plants.domain.Domain.provides`)."""
    from tspend.plants.registry import domain_of

    domain = domain_of(scenario.plant.kind)
    why = (cls or kind_class(kind)).unsupported(domain)
    if why is None:
        return None
    return (f"{scenario.path}: controller '{kind}' cannot run on plant '{scenario.plant.kind}' "
            f"(domain {domain.name}): {why}")


def kinds_table() -> str:
    """docs/controllers.md's table of built-in kinds x registered domains, in Markdown, from
    what each kind declares (``needs``, ``domains``, ``guarantees``) and what each domain
    provides: a cell says ``yes`` or what is missing (tests/test_furuta_control.py checks
    the page against it)."""
    from tspend.plants.domain import CAPABILITIES
    from tspend.plants.registry import DOMAINS

    names = list(DOMAINS)
    lines = ["| kind | needs | " + " | ".join(names) + " | what it guarantees |",
             "|---|---|" + "---|" * len(names) + "---|"]
    for kind in KINDS:
        cls = kind_class(kind)
        needs = "; ".join(CAPABILITIES[n] for n in cls.needs) or "the view only"
        cells = []
        for d in DOMAINS.values():
            missing = [n for n in cls.needs if n not in d.provides]
            off = cls.domains and d.name not in cls.domains
            cells.append("no (" + ", ".join(missing) + ")" if missing else "no" if off else "yes")
        lines.append(f"| `{kind}` | {needs} | " + " | ".join(cells) + f" | {cls.guarantees} |")
    return "\n".join(lines)


def available() -> list[Kind]:
    """Every kind by name: the built-in ones, then those installed packages register."""
    kinds = [resolve(k) for k in KINDS]
    for name in plugins.entry_point_names(ENTRY_POINT_GROUP):
        try:
            found = resolve(name)
            # listed by the name one types; the kind it reports, when another, in the line
            summary = found.summary + (f" (kind {found.name})" if found.name != name else "")
            kinds.append(replace(found, name=name, summary=summary))
        except ScenarioError as exc:
            kinds.append(Kind(name, _unloadable(f"--controller {name}: {exc}"), None,
                              f"(cannot be loaded: {exc})"))
    return kinds


def _unloadable(message: str) -> Callable[..., Controller]:
    """The builder of a listed plug-in that cannot be loaded: it refuses in one line."""
    def build(scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        raise ScenarioError(message)

    return build


def _plain_text(text: str) -> str:
    """RST inline markup (``code``, `name`) removed: ``--controller help`` is plain text."""
    return re.sub(r"`{1,2}([^`]*)`{1,2}", r"\1", text)


def help_text() -> str:
    """``--controller help``: one line per kind, and how to name one's own."""
    kinds = available()
    width = max(len(k.name) for k in kinds)
    # plain text: the docstrings' RST markup (``code``, `name`) is for the docs
    lines = [f"{k.name:<{width}}  {_plain_text(k.summary)}" for k in kinds]
    lines.append(f"{'FILE.py:Class':<{width}}  your own controller (docs/writing-a-controller.md;"
                 f" also package.module:Class)")
    lines.append(f"{'KIND' + safety.SUFFIX:<{width}}  any kind behind the CBF safety filter "
                 f"(docs/safety.md)")
    return "\n".join(lines) + "\n"


def settings_class(name: str) -> type | None:
    """The settings dataclass of the kind called ``name``, or None when no kind is.

    Besides the built-in kinds: installed entry points, and the plug-ins this process has
    loaded (so a plug-in named on the command line has its ``[controllers.NAME]`` table
    and ``--set`` overrides validated like a built-in kind's).
    """
    if name in KINDS:
        return _table_settings(KINDS[name])
    if name.endswith(safety.SUFFIX) and name != safety.SUFFIX:
        return settings_class(name[:-len(safety.SUFFIX)])
    if name in _LOADED:
        return _LOADED[name]
    if name in plugins.entry_point_names(ENTRY_POINT_GROUP):
        return resolve(name, f"[controllers.{name}]").settings
    return None


class _KindSettingsView(Mapping):
    """Kind name -> settings class, over :func:`settings_class` (for the scenario reader)."""

    def __getitem__(self, name: str) -> type:
        cls = settings_class(name)
        if cls is None:
            raise KeyError(name)
        return cls

    def __iter__(self):
        return iter([*(k for k, c in KINDS.items() if _table_settings(c)), *_LOADED])

    def __len__(self) -> int:
        return len(list(iter(self)))


def settings_classes() -> Mapping[str, type]:
    """Every kind's settings class by name, plug-ins included (see :func:`settings_class`);
    what the scenario reader validates ``[controllers.KIND]`` tables against."""
    return _KindSettingsView()


#: plug-in kind name -> its settings dataclass, for plug-ins loaded by :func:`load`.  A
#: cache of what this process imported (like ``sys.modules``), so the scenario reader
#: can validate their tables; it changes no result.
_LOADED: dict[str, type] = {}


def search_space(kind: str) -> "dict[str, Search]":
    """The declared search space of ``kind``: ``{key in the file: Search}``."""
    from tspend.controllers.settings import search_table

    if kind in KINDS and KINDS[kind].Settings is not None:
        return search_table(kind, KINDS[kind].Settings.SEARCH)  # type: ignore[union-attr]
    raise ValueError(f"unknown controller kind {kind!r}; allowed: {', '.join(KINDS)}")


def load(spec: str, option: str = "--controller") -> Kind:
    """:func:`resolve`, remembering a plug-in's settings class for the scenario reader.

    Call it before the scenario is read when the scenario may carry the plug-in's table.
    """
    kind = resolve(spec, option)
    if kind.source and kind.settings is not None:
        _LOADED[kind.name] = kind.settings
    return kind


def settings_of(scenario: "Scenario", kind_name: str | None) -> dict[str, Any]:
    """The settings the kind runs with, as plain values (for the metrics JSON)."""
    from tspend.controllers.settings import settings_for

    if kind_name is None:
        return _plain(dataclasses.asdict(scenario.controller))
    if kind_name in KINDS:
        own = KINDS[kind_name].settings_in(scenario)
        return _plain(dataclasses.asdict(own)) if own is not None else {}
    cls = settings_class(kind_name)
    if cls is None:
        return {}
    return _plain(dataclasses.asdict(settings_for(scenario, cls)))


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float) and value != value:
        return None
    return value


def build(scenario: "Scenario", kind: str | None = None,
          machine: "Plant | None" = None) -> Controller:
    """The controller ``kind`` for ``scenario`` (``None``: the scenario's own controller),
    behind the safety filter when the scenario's ``[safety]`` asks for one (or the kind is
    spelled ``KIND+cbf``): the filter :data:`SAFETY_FILTERS` names.

    ``kind`` is any spec :func:`resolve` accepts; ``machine`` the nominal machine the
    runner built for a kind that designs on one (:func:`needs_machine`;
    :func:`tspend.loop.simulation.nominal_machine`).
    """
    ctrl = _build(scenario, kind, machine)
    chosen = SAFETY_FILTERS.get(scenario.safety.filter)
    if chosen is not None and not isinstance(ctrl, safety.SafetyFilter):
        ctrl = chosen.wrap(scenario, ctrl, machine)
    return ctrl


def _build(scenario: "Scenario", kind: str | None, machine: "Plant | None") -> Controller:
    if kind is None:
        kind = scenario.run.controller or None   # the scenario's own kind ([run] controller)
    if kind is None:
        from tspend.controllers.paper.controller import make_controller

        return make_controller(scenario.controller)  # the file's [controller] as it is
    found = load(kind)
    refused = unsupported(scenario, kind, found.cls)
    if refused:
        raise ScenarioError(refused)
    if not found.source:
        return found.build(scenario, machine)
    try:
        ctrl = found.build(scenario, machine)
    except ScenarioError:
        raise
    except BaseException as exc:  # the user's code (sys.exit too): one line, exit 2, nothing written
        from tspend.runtime.plugins import failure_text, own_failure

        if not own_failure(exc):
            raise
        raise ScenarioError(f"--controller {kind}: building it failed: {failure_text(exc)}") \
            from None
    if not isinstance(ctrl, Controller):
        raise ScenarioError(f"--controller {kind}: built a {type(ctrl).__name__}, not a "
                            f"Controller (see docs/writing-a-controller.md)")
    order = getattr(ctrl, "order", None)  # the user's object: its declared attributes, checked once here
    if not isinstance(order, int) or isinstance(order, bool) or order < 1:
        raise ScenarioError(f"--controller {kind}: its 'order' must be a positive int (the "
                            f"plant's order n), got {order!r:.40} (see "
                            f"docs/writing-a-controller.md)")
    return ctrl


__all__ = ["KINDS", "kind_class", "needs_machine", "kinds_table", "unsupported",
           "search_space", "ENTRY_POINT_GROUP", "Controller", "Diagnostic", "Kind",
           "available", "build", "help_text", "load", "resolve", "settings_class",
           "settings_classes", "settings_of"]
