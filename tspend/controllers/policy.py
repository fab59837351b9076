"""``policy``: a learned policy, an ONNX graph run by onnxruntime on the gym env's observation.

The graph takes what :class:`tspend.gym.TspendEnv` observes, one row of float32 (or
float64): the plant's full state (the view's entries as the controller measures them),
then the reference and its derivatives ``r, r', .., r^(n)``; it returns ``u`` (the
actuator's unit; the plant clips it to the actuator's bounds).  Normalisation, the choice
of inputs and scaling live inside the graph (``benchmarks/train_policy.py`` bakes them in).

The model's metadata (``metadata_props``) may say what it was made for; each key is
checked when present: ``tspend.plant_kind`` (the domain must match), ``tspend.view``
(JSON list of the view's state names: where the measured view goes),
``tspend.observation_names`` (JSON list: the full state's names must match the plant's at
the first sample), ``tspend.control_period`` (s: the default of ``period``).

Settings (``[controllers.policy]``): ``path`` (the .onnx file: absolute, or relative to
the working directory, the scenario's directory or the project), ``period`` (s; default:
the model's ``tspend.control_period``, else every step).  docs/gym.md.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.controllers.base import Controller, Observation
from tspend.controllers.settings import KindSettings, setting, settings_for
from tspend.runtime.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario

__all__ = ["PolicyController", "PolicySettings", "build", "find_policy"]


@dataclass(frozen=True)
class PolicySettings(KindSettings):
    """``[controllers.policy]``."""

    path: str = setting("", "the policy's .onnx file (relative: to the working directory, "
                            "the scenario's directory, then the project)", kind="string")
    period: float | None = setting(None, "s between evaluations, u held in between "
                                         "(default: the model's tspend.control_period)",
                                   low=0.0)

    def check(self, n: int):
        if not self.path.strip():
            return "path", "must name an .onnx file"
        return None


def find_policy(path: str, scenario: "Scenario") -> Path:
    """The file ``path`` names, looked for like a scenario's MJCF (ScenarioError if none)."""
    from tspend.shipped import find_named_file

    return find_named_file(path, scenario, "controllers.policy.path")


class PolicyController(Controller):
    """The ``policy`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "policy"
    Settings = PolicySettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    guarantees = ("none beyond what its training showed: it runs on the machine and "
                  "observation layout it was trained on (checked against the model's metadata)")

    def __init__(self, session: Any, order: int, metadata: dict[str, str], period: float,
                 source: str) -> None:
        self.session = session
        self.order = order
        self.sample_period = period
        self.source = source
        self.diag = np.zeros(0)
        inp = session.get_inputs()[0]
        self._input = inp.name
        self._dtype = np.float64 if inp.type == "tensor(double)" else np.float32
        self._width = inp.shape[-1] if isinstance(inp.shape[-1], int) else None
        self._view = tuple(json.loads(metadata["tspend.view"])) \
            if "tspend.view" in metadata else None
        names = metadata.get("tspend.observation_names")
        self._names = tuple(json.loads(names)) if names else None
        self._view_index: np.ndarray | None = None
        self._row: np.ndarray | None = None

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn (the policy is deterministic)."""
        self._view_index = None

    def _layout(self, obs: Observation) -> None:
        """Where the measured view goes, checked once against the model's metadata."""
        N = len(obs.state)
        width = N + len(obs.ref)
        where = f"controllers.policy.path = {self.source}"
        if self._width is not None and self._width != width:
            raise ScenarioError(f"{where}: the model takes {self._width} inputs, this plant "
                                f"and task give {width} (full state + reference)")
        if self._names is not None and obs.names and tuple(self._names[:N]) != tuple(obs.names):
            raise ScenarioError(f"{where}: trained on states {', '.join(self._names[:N])}, "
                                f"this plant has {', '.join(obs.names)}")
        view = self._view
        if view is None or not obs.names:
            self._view_index = np.zeros(0, dtype=np.intp)
        else:
            self._view_index = np.array([obs.names.index(v) for v in view], dtype=np.intp)
        self._row = np.zeros((1, width), dtype=self._dtype)

    def step(self, obs: Observation, dt: float) -> float:
        if self._view_index is None:
            self._layout(obs)
        row = self._row
        N = len(obs.state)
        row[0, :N] = obs.state
        if self._view_index.size:
            # the view as the controller measures it (sensor noise, delay), as the env does
            row[0, self._view_index] = obs.x
        row[0, N:] = obs.ref
        out = self.session.run(None, {self._input: row})[0]
        return float(np.asarray(out).reshape(-1)[0])


def build(scenario: "Scenario", machine: "Plant | None" = None) -> PolicyController:
    s: PolicySettings = settings_for(scenario, PolicySettings)
    where = f"{scenario.path or scenario.name}: controllers.policy"
    if not s.path.strip():
        raise ScenarioError(f"{where}.path: not set (the kind 'policy' runs an .onnx file: "
                            f"[controllers.policy] path = \"...\")")
    path = find_policy(s.path, scenario)
    try:
        import onnxruntime
    except ImportError:
        raise ScenarioError("the kind 'policy' needs onnxruntime: pip install 'tspend[rl]'") \
            from None
    from tspend.plants import registry

    try:
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1   # a tiny graph per sample: threads only cost
        options.inter_op_num_threads = 1
        options.log_severity_level = 4     # its own errors become the one line below
        session = onnxruntime.InferenceSession(str(path), options,
                                               providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own classes for a bad file
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ScenarioError(f"{where}.path = {s.path!r}: not an ONNX model onnxruntime can "
                            f"load ({first[:200]})") from None
    inputs, outputs = session.get_inputs(), session.get_outputs()
    if len(inputs) != 1 or len(outputs) < 1:
        raise ScenarioError(f"{where}.path = {s.path!r}: the model must take one input (the "
                            f"observation) and return u first; it has {len(inputs)} inputs")
    meta = dict(session.get_modelmeta().custom_metadata_map)
    trained = meta.get("tspend.plant_kind")
    kind = scenario.plant.kind
    if trained and trained in registry.PLANT_KINDS and \
            registry.domain_of(trained).name != registry.domain_of(kind).name:
        raise ScenarioError(f"{where}.path = {s.path!r}: trained on plant kind {trained}, the "
                            f"scenario's is {kind} (another machine)")
    order = registry.PLANT_KINDS[kind].order
    view = json.loads(meta["tspend.view"]) if "tspend.view" in meta else None
    if view is not None and len(view) != order:
        raise ScenarioError(f"{where}.path = {s.path!r}: trained on a view of {len(view)} "
                            f"states, this plant's task has {order}")
    period = s.period
    if period is None:
        try:
            period = float(meta.get("tspend.control_period", "0"))
        except ValueError:
            period = math.nan
        if not (period >= 0.0 and math.isfinite(period)):
            raise ScenarioError(f"{where}.path = {s.path!r}: metadata tspend.control_period "
                                f"= {meta.get('tspend.control_period')!r} is not a period")
    return PolicyController(session, order, meta, float(period), s.path)
