"""``tspend.linearize``: a plant as a continuous-time python-control ``StateSpace``.

    s' ~ A (s - s*) + B u,      y = C (s - s*)

about a full state ``s*`` (default the upright at rest, ``s* = 0``) with ``u = 0``, the
state in the plant's own order and names (``plant.state_names``), the input named after
the actuator (``plant.inputs``) and the output the task's tracked one (the pole's angle:
the first entry of the task's view).

Where ``A, B`` come from:

* **an MJCF plant** (``cartpole_mujoco``, ``furuta_mujoco``): MuJoCo's own forward
  dynamics, central differences of ``mj_forward``'s ``qacc`` against ``qpos``, ``qvel``
  and ``ctrl`` (:func:`mujoco_jacobians`).  That is the continuous-time derivative of the
  model MuJoCo compiled, whatever its integrator: ``mujoco.mjd_transitionFD`` would give
  the discrete map of one step of it instead, and refuses RK4 models.
* **an analytic plant**: the domain's exact Jacobian
  (:meth:`~tspend.plants.domain.Domain.jacobians`: CasADi's derivatives of the derived equations of
  every MJCF machine, the same functions ``lqr``'s full design takes its model
  from); where the domain has no closed form (a moving state, the paper's chain plants)
  central differences of the plant's own right-hand side.

Dry friction has no linear model at rest: MuJoCo's ``frictionloss`` is a soft constraint
whose derivative there is a stiff viscous term (``pendulum_friction``: poles near -90 1/s),
and the ODE's smooth ``F tanh(v / v_s)`` has slope ``F / v_s``.  Linearise such a machine
away from rest, or its frictionless twin.

The central differences' step ``h = FD_STEP (1 + |v|)`` leaves a truncation error
``~h^2`` and a rounding error ``~1e-16 / h``: ~1e-10 relative on the plants here.

python-control is a core dependency.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.plants.analytic import AnalyticPlant
from tspend.plants.base import Plant, velocity_name
from tspend.plants.domain import FD_STEP

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["linearize", "jacobians", "mujoco_jacobians", "FD_STEP"]


def mujoco_jacobians(model: Any, state_names: tuple[str, ...], actuator: str,
                     at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time ``(A, B)`` of an MJCF at the full state ``at``, ``ctrl = 0``.

    ``state_names`` are 1-DOF joints' names (their ``qpos``), then ``<joint>_dot`` (their
    ``qvel``), covering every degree of freedom of ``model``; ``actuator`` is the input.
    Each column is a central difference of ``mj_forward``'s ``qacc``.
    """
    import mujoco

    N = len(state_names)
    dof = N // 2
    if N != 2 * dof or dof != model.nq or model.nq != model.nv:
        raise ScenarioError(f"linearize: the state ({', '.join(state_names)}) is not the "
                            f"model's qpos and qvel (nq = {model.nq}, nv = {model.nv})")
    qadr, vadr = [], []
    for name, vel in zip(state_names[:dof], state_names[dof:]):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0 or vel != velocity_name(name):
            raise ScenarioError(f"linearize: state {name!r}/{vel!r} is not a joint of the model")
        qadr.append(int(model.jnt_qposadr[j]))
        vadr.append(int(model.jnt_dofadr[j]))
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
    if act < 0:
        raise ScenarioError(f"linearize: no actuator named {actuator!r} in the model")

    data = mujoco.MjData(model)
    data.qpos[qadr] = at[:dof]
    data.qvel[vadr] = at[dof:]
    data.ctrl[:] = 0.0
    mujoco.mj_forward(model, data)
    # a constraint solver warm-starts from the last solution: start every evaluation from
    # the same one, so the differences see the state, not the order of the calls
    warm = data.qacc_warmstart.copy()

    def qacc() -> np.ndarray:
        data.qacc_warmstart[:] = warm
        mujoco.mj_forward(model, data)
        return data.qacc[vadr].copy()

    def column(buf: np.ndarray, i: int) -> np.ndarray:
        v = float(buf[i])
        h = FD_STEP * (1.0 + abs(v))
        buf[i] = v + h
        up = qacc()
        buf[i] = v - h
        down = qacc()
        buf[i] = v
        return (up - down) / (2.0 * h)

    A = np.zeros((N, N))
    A[:dof, dof:] = np.eye(dof)
    for k in range(dof):
        A[dof:, k] = column(data.qpos, qadr[k])
        A[dof:, dof + k] = column(data.qvel, vadr[k])
    B = np.zeros((N, 1))
    B[dof:, 0] = column(data.ctrl, act)
    return A, B


def _rhs_jacobians(plant: AnalyticPlant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of an analytic plant's right-hand side, in full-state order."""
    order = np.asarray(plant.full_order)
    s0 = np.empty(order.size)
    s0[order] = at

    def f(s: np.ndarray, u: float) -> np.ndarray:
        return plant.rhs(0.0, s, u, 0.0)[order]

    N = at.size
    A = np.empty((N, N))
    for i in range(N):
        h = FD_STEP * (1.0 + abs(at[i]))
        sp, sm = s0.copy(), s0.copy()
        sp[order[i]] += h
        sm[order[i]] -= h
        A[:, i] = (f(sp, 0.0) - f(sm, 0.0)) / (2.0 * h)
    h = FD_STEP
    B = ((f(s0, h) - f(s0, -h)) / (2.0 * h))[:, None]
    return A, B


def jacobians(plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of ``plant`` at the full state ``at``, ``u = 0`` (module docstring)."""
    from tspend.plants.registry import DOMAINS

    model = plant.mj_model()
    if model is not None:
        return mujoco_jacobians(model, tuple(plant.state_names), plant.inputs[0].name, at)
    domain = DOMAINS.get(plant.domain)
    exact = domain.jacobians(plant, at) if domain is not None else None
    if exact is not None:
        return exact
    if isinstance(plant, AnalyticPlant):
        return _rhs_jacobians(plant, at)
    raise ScenarioError(f"linearize: plant {plant.name!r} is neither an MJCF nor an analytic "
                        f"plant; nothing to differentiate")


def _operating_point(plant: Plant, at: Any) -> np.ndarray:
    names = tuple(plant.state_names)
    if at is None:
        return np.zeros(len(names))
    if isinstance(at, Mapping):
        s = np.zeros(len(names))
        for key, value in at.items():
            if key not in names:
                raise ScenarioError(f"linearize: at: no state named {key!r} "
                                    f"(states: {', '.join(names)})")
            s[names.index(key)] = float(value)
    else:
        try:
            s = np.asarray(at, dtype=float)
        except (TypeError, ValueError):
            raise ScenarioError(f"linearize: at: a dict of state names or {len(names)} "
                                f"numbers, got {at!r}") from None
        if s.shape != (len(names),):
            raise ScenarioError(f"linearize: at: {len(names)} entries "
                                f"({', '.join(names)}), got shape {s.shape}")
    if not all(math.isfinite(v) for v in s):
        raise ScenarioError(f"linearize: at: not finite: {s.tolist()}")
    return s


def _plant_and_output(scenario_or_plant: Any) -> tuple[Plant, str, str]:
    """The plant, its tracked output's name and the system's name."""
    if isinstance(scenario_or_plant, Plant):
        plant = scenario_or_plant
        return plant, plant.default_task().view[0], plant.name
    from os import PathLike

    from tspend.config import Scenario
    from tspend.plants import registry
    from tspend.task import build_task

    if isinstance(scenario_or_plant, (str, PathLike)):
        from tspend.scenario import load_scenario

        scenario: "Scenario" = load_scenario(scenario_or_plant)
    elif isinstance(scenario_or_plant, Scenario):
        scenario = scenario_or_plant
    else:
        raise ScenarioError(f"linearize: a scenario name, a path, a Scenario or a Plant, got "
                            f"{type(scenario_or_plant).__name__}")
    plant = registry.build(scenario)
    task = build_task(plant, scenario.task, scenario.effects, where=str(scenario.path))
    return plant, task.view[0], scenario.name or plant.name


def linearize(scenario_or_plant: Any, at: Any = None) -> Any:
    """The plant linearised about ``at`` as a continuous-time ``control.StateSpace``.

    Parameters
    ----------
    scenario_or_plant : str, path, Scenario or Plant
        A scenario's name (``tspend list``), a ``.toml`` path, a
        :class:`~tspend.config.Scenario` or a built :class:`~tspend.plants.base.Plant`.
    at : dict or array, optional
        The full state to linearise about: ``{"hinge": 0.1}`` (the rest 0) or every entry
        in ``plant.state_names`` order.  Default: all zeros, the upright at rest.

    Returns
    -------
    control.StateSpace
        ``A, B, C, D`` with ``u = 0``; states named as the plant's, the input after its
        actuator, the output the task's tracked state (``y = C s``, ``D = 0``).

    Raises
    ------
    ScenarioError
        python-control missing, an unknown scenario, a bad ``at``, or a plant with nothing
        to differentiate.
    """
    from tspend.runtime.extras import missing_extra

    problem = missing_extra("control", "linearize")
    if problem:
        raise ScenarioError(problem)
    import control
    plant, output, name = _plant_and_output(scenario_or_plant)
    s = _operating_point(plant, at)
    A, B = jacobians(plant, s)
    names = tuple(plant.state_names)
    C = np.zeros((1, len(names)))
    C[0, names.index(output)] = 1.0
    return control.ss(A, B, C, np.zeros((1, 1)), states=list(names),
                      inputs=[plant.inputs[0].name], outputs=[output], name=name)
