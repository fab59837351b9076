"""Whether a cart-pole task can be done at all, before a run: the task's side of the machine.

The physics says what the actuator can give (:func:`tspend.plants.mjcf.actuator_force_range`);
the task says what the reference and the disturbance ask.  :func:`check_cart_force`
compares the two for a balancing task (one that ends on a fall) and refuses, with the
reason, a run no controller could finish.  :func:`check_task` is what the runners call
before a run, for any plant: the task side depends on the physics, never the reverse.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.plants.articulated.domain import applied_forces
from tspend.plants.base import CartPolePlant, MachinePlant, read_as
from tspend.plants.mjcf import CartPoleParams, actuator_force_range

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.plants.articulated.machine import Machine
    from tspend.plants.base import Plant
    from tspend.task import Task

__all__ = ["check_task", "check_cart_force", "reference_force", "inverse_dynamics", "NEED_SAMPLES"]


def inverse_dynamics(machine: Machine, q: float, w: float, q_dd: float, cart_vel: float,
                     d_torque: float, dry: np.ndarray) -> tuple[float, float]:
    """``(F, x'')`` of the derived equations ``M(q) q'' = r(q, q', u) + qfrc``: the
    generalised force on the cart and its acceleration that give the pole ``q'' = q_dd``
    at ``(q, q')`` with the cart at 0 moving at ``cart_vel`` (the pole's row solved for
    x'', then the cart's for F), the actuator, the cart's spring, the disturbance's hinge
    torque ``d_torque`` and each joint's smooth dry friction ``dry`` (the ODE twin's).
    ``F`` is +/-inf where the rail cannot move the pole."""
    nv = machine.nv
    c, h = next(i for i, j in enumerate(machine.tree.joints) if j.kind == "slide"), machine.view_joint
    p = machine.p.copy()
    for i, name in enumerate(machine.parameter_names):
        if name.endswith(".gear") or name == f"{machine.joint_names[c]}.stiffness":
            p[i] = 0.0  # no actuator (F is its force), the cart's position free
    s = np.zeros(2 * nv)
    s[h], s[nv + h], s[nv + c] = q, w, cart_vel
    qfrc = np.zeros(nv)
    applied_forces(qfrc, s, h, 1.0, d_torque, dry)
    M, r = np.zeros(nv * nv), np.zeros(nv)
    machine.module.dynamics(s[:nv], s[nv:], np.zeros(len(machine.tree.actuators)), qfrc, p, M, r)
    M = M.reshape(nv, nv)
    if M[h, c] == 0.0:
        return math.copysign(math.inf, r[h] - M[h, h] * q_dd), math.nan
    x_dd = (r[h] - M[h, h] * q_dd) / M[h, c]
    return float(M[c, c] * x_dd + M[c, h] * q_dd - r[c]), float(x_dd)


#: samples of r(t) the task check evaluates the need on (at most)
NEED_SAMPLES = 4000


def reference_force(p: CartPoleParams, scenario: "Scenario", machine: Machine
                    ) -> tuple[float, float, float] | None:
    """``(t, least, largest)`` cart force the machine needs to follow the scenario's
    reference with its disturbance (``t``: when the larger need in size is); None when
    the reference is not smooth enough to have ``r''``: the inverse dynamics of
    ``machine``'s derived equations (:func:`inverse_dynamics`), the friction of
    ``p``."""
    n = int(min(NEED_SAMPLES, max(2, round(scenario.run.duration / scenario.run.dt))))
    t = np.linspace(0.0, scenario.run.duration, n + 1)
    try:
        r = scenario.reference.derivatives(t, 2)
    except (ValueError, NotImplementedError):
        return None
    d = np.asarray(scenario.disturbance(t), dtype=float)
    dry = np.zeros(machine.nv)
    dry[[j.kind for j in machine.tree.joints].index("slide")] = p.cart_friction
    dry[machine.view_joint] = p.hinge_friction
    force = np.empty(n + 1)
    v = 0.0
    for k in range(n + 1):
        force[k], x_dd = inverse_dynamics(machine, r[k, 0], r[k, 1], r[k, 2], v,
                                                   p.disturbance_torque * d[k], dry)
        if k < n and math.isfinite(x_dd):
            v += x_dd * (t[k + 1] - t[k])
    k_lo, k_hi = int(np.argmin(force)), int(np.argmax(force))
    k = k_hi if abs(force[k_hi]) >= abs(force[k_lo]) else k_lo
    return float(t[k]), float(force[k_lo]), float(force[k_hi])


def check_cart_force(plant: "Plant", machine: "Machine", task: "Task", scenario: "Scenario") -> None:
    """Before a balancing run (the task ends on a fall): the force the reference and the
    disturbance need against what ``plant``'s actuator can give.

    The need is the inverse dynamics along ``r(t)`` over the run (of ``machine``, the
    equations derived from the compiled model, :func:`inverse_dynamics`), the cart's
    velocity integrated from rest: a lower bound (a controller also has to bring x0 to r
    and hold the cart).  The actuator's force is at rest, over ``ctrlrange`` (and
    ``effects.saturation``), ``forcerange`` and the joint's ``actuatorfrcrange``.
    ScenarioError when the need exceeds it.
    """
    if not any(limit is not None and limit.status == "fell" for limit in task.lo_limits):
        return
    p = read_as(plant, CartPolePlant).params
    sat = scenario.effects.saturation
    lo, hi = actuator_force_range(p, -sat if sat > 0 else -math.inf,
                                  sat if sat > 0 else math.inf)
    if lo == -math.inf and hi == math.inf:
        return
    need = reference_force(p, scenario, machine)
    if need is None:
        return
    t, f_lo, f_hi = need
    if f_hi <= hi and f_lo >= lo:
        return
    worst = f_hi if f_hi > hi else f_lo
    name = plant.inputs[0].name if plant.inputs else "u"
    raise ScenarioError(
        f"{scenario.path or scenario.name}: the task cannot be done: following the "
        f"reference (with the disturbance) needs a cart force of {worst:.4g} N (at "
        f"t = {t:.4g} s) and actuator '{name}' gives {lo:.4g} .. {hi:.4g} N at rest "
        f"(gear {p.gear:g} x gain {p.gain:g} x u in [{max(p.ctrl_min, -sat if sat > 0 else -math.inf):g}, "
        f"{min(p.ctrl_max, sat if sat > 0 else math.inf):g}]); lower reference.amplitude "
        f"or widen the actuator's range")


def check_task(plant: "Plant", task: "Task", scenario: "Scenario") -> None:
    """Raise ScenarioError, before a run, when ``plant`` plainly cannot do ``task``: a
    cart-pole's actuator weaker than the reference needs (:func:`check_cart_force`); no
    other plant is checked."""
    inner = plant.underlying()
    if isinstance(inner, CartPolePlant) and isinstance(inner, MachinePlant):
        check_cart_force(plant, inner.machine, task, scenario)
