"""Controllers behind one protocol (:mod:`tspend.controllers.base`), chosen by kind.

``KINDS`` maps each kind to the function that builds it from a scenario: the paper's
``second_type`` (the default) and ``first_type`` (antecedents fixed), and the baselines
to compare them with, one module each (``pd``, ``lqr``, ``feedback_linearization``,
``sliding_mode``, ``wang_indirect``; see docs/controllers.md).  A builder takes the
scenario and the keyword options, and returns a controller that has not been reset yet.
``SETTINGS`` maps each baseline kind to its settings dataclass, read from the scenario's
``[controllers.KIND]`` table (:mod:`.settings`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Callable

from tspend.controllers import feedback_linearization, lqr, pd, sliding_mode, swingup, wang_indirect
from tspend.controllers import mpc
from tspend.controllers.base import Controller, Diagnostic

if TYPE_CHECKING:
    from tspend.config import Scenario


def _paper(adaptation: str | None) -> Callable[..., Controller]:
    def build(scenario: "Scenario") -> Controller:
        from tspend.controllers.paper.controller import make_controller

        cfg = scenario.controller
        if adaptation is not None and cfg.adaptation != adaptation:
            cfg = replace(cfg, adaptation=adaptation)
        return make_controller(cfg)

    return build


#: controller kind -> builder(scenario, **options)
KINDS: dict[str, Callable[..., Controller]] = {
    "second_type": _paper("second"),
    "first_type": _paper("first"),
    "pd": pd.build,
    "lqr": lqr.build,
    "feedback_linearization": feedback_linearization.build,
    "sliding_mode": sliding_mode.build,
    "wang_indirect": wang_indirect.build,
    "swingup": swingup.build,
    "mpc": mpc.build,
}

#: baseline kind -> its settings dataclass, read from [controllers.KIND]
SETTINGS: dict[str, type] = {
    "pd": pd.PDSettings,
    "lqr": lqr.LQRSettings,
    "feedback_linearization": feedback_linearization.FeedbackLinearizationSettings,
    "sliding_mode": sliding_mode.SlidingModeSettings,
    "wang_indirect": wang_indirect.WangSettings,
    "swingup": swingup.SwingUpSettings,
    "mpc": mpc.MPCSettings,
}


def build(scenario: "Scenario", kind: str | None = None, **options) -> Controller:
    """The controller ``kind`` for ``scenario`` (``None``: the scenario's own controller)."""
    if kind is None:
        kind = scenario.run.controller or None   # the scenario's own kind ([run] controller)
    if kind is None:
        return _paper(None)(scenario, **options)
    try:
        builder = KINDS[kind]
    except KeyError:
        raise ValueError(f"unknown controller kind {kind!r}; allowed: {', '.join(KINDS)}") from None
    return builder(scenario, **options)


__all__ = ["KINDS", "SETTINGS", "Controller", "Diagnostic", "build"]
