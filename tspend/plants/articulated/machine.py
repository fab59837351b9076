"""One articulated machine: a compiled MJCF, its tree, its derived equations and its roles.

:class:`Machine` is what both backends and the domain share: the model as MuJoCo
compiled it, :func:`.tree.read_tree`'s facts, :func:`.derive.derive`'s equations with
the parameter vector of this model, the numba module that steps them, and each joint's
role (:data:`.tree.ROLES`), inferred from the equations themselves:

* a slide joint is a ``cart`` (its range is the rail);
* a hinge about which gravity does work (dV/dq != 0 somewhere) is a ``pole``: the task
  keeps it within the fall angle of its upright, q = 0;
* a hinge about which gravity does no work is an ``arm`` when its axis is along gravity
  (the Furuta's), else a ``rotor`` (a balanced wheel): neither is bounded by the task.

A scenario may name the poles itself (``plant.poles``).
"""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.plants.articulated.derive import Derivation, compiled_module, derive, parameter_table
from tspend.plants.articulated.tree import INTEGRATOR_NAMES, Tree, read_tree

__all__ = ["Machine", "load_machine", "open_spec"]

_DERIVED: dict[str, Derivation] = {}

#: the unit of a ``u`` that is an actuator's control, not a force (a geared motor's): the
#: force it applies is beside it (:attr:`Machine.force_per_unit`)
CONTROL_UNIT = "ctrl"


def derivation_of(tree: Tree) -> Derivation:
    """``tree``'s equations, derived once per process for each tree shape (the numbers of
    a model are the parameter vector, not part of the derivation)."""
    from dataclasses import replace

    from tspend.plants.articulated.derive import parameter_table

    key = tree.structure_key()
    d = _DERIVED.get(key)
    if d is None:
        d = derive(tree)
        _DERIVED[key] = d
    names, nominal = parameter_table(tree)
    return replace(d, tree=tree, names=names, nominal=nominal)


class Machine:
    """A compiled MJCF as the articulated domain reads it (module docstring).

    ``actuator``: the actuator ``u`` drives ("" = the model's only one); ``poles``: the
    joints the task keeps upright (() = inferred); ``where``: the model's name in errors.
    """

    def __init__(self, model: Any, where: str, actuator: str = "", poles: tuple[str, ...] = ()) -> None:
        self.model, self.where = model, where
        self.tree = read_tree(model)
        if self.tree.refusals:
            raise ScenarioError(f"{where}: cannot derive its equations: {'; '.join(self.tree.refusals)}"
                                f" (change the model so it has none of these: docs/articulated.md "
                                f"lists what is derived)")
        if not self.tree.actuators:
            raise ScenarioError(f"{where}: the model has no actuator to drive")
        names = [a.name for a in self.tree.actuators]
        if actuator:
            if actuator not in names:
                raise ScenarioError(f"{where}: no actuator named {actuator!r} (actuators: "
                                    f"{', '.join(names)})")
            self.actuator_index = names.index(actuator)
        elif len(names) == 1:
            self.actuator_index = 0
        else:
            raise ScenarioError(f"{where}: {len(names)} actuators ({', '.join(names)}); name the one "
                                f"u drives with plant.actuator")
        self.parameter_names, nominal = parameter_table(self.tree)
        self.module = compiled_module(self.tree, lambda: self.derivation)
        self.p = nominal.copy()
        nv = self.tree.nv
        self._M, self._r = np.zeros(nv * nv), np.zeros(nv)
        self._u, self._qfrc = np.zeros(len(self.tree.actuators)), np.zeros(nv)
        self.roles = self._roles(poles)

    @cached_property
    def derivation(self) -> Derivation:
        """The equations over CasADi (derived on first use: a cached module needs none)."""
        return derivation_of(self.tree)

    # -- names ------------------------------------------------------------------------
    @property
    def nv(self) -> int:
        return self.tree.nv

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.tree.joint_names

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.joint_names + tuple(f"{n}_dot" for n in self.joint_names)

    @property
    def state_units(self) -> tuple[str, ...]:
        pos = tuple("m" if j.kind == "slide" else "rad" for j in self.tree.joints)
        return pos + tuple(f"{u}/s" for u in pos)

    @property
    def actuator(self):
        return self.tree.actuators[self.actuator_index]

    @property
    def actuated(self) -> int:
        """The index of the joint ``u`` drives."""
        return self.actuator.joint

    @cached_property
    def input_unit(self) -> str:
        """``u``'s unit: the model's ``<custom><text name="tspend:unit:ACTUATOR" data=...>``
        when given; else V for a motor with back-EMF (a velocity bias), else the force or
        torque of its joint."""
        m = self.model
        import mujoco

        key = f"tspend:unit:{self.actuator.name}"
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXT, key)
        if i >= 0:
            adr, size = int(m.text_adr[i]), int(m.text_size[i])
            return bytes(m.text_data[adr:adr + size]).split(b"\0")[0].decode()
        if self.actuator.bias[2] != 0.0:
            return "V"
        if self.force_per_unit != 1.0:
            # a geared motor or a gain other than 1: u is the actuator's control, not the
            # force (the force is force_per_unit u at rest): "ctrl", its control units
            return CONTROL_UNIT
        return self.force_unit

    @property
    def force_unit(self) -> str:
        """The unit of the generalised force the actuator applies to its joint."""
        return "N" if self.tree.joints[self.actuated].kind == "slide" else "N m"

    @property
    def force_per_unit(self) -> float:
        """The force (torque) on the actuated joint per unit of ``u`` at rest: gear x gain."""
        return float(self.actuator.gear * self.actuator.gain[0])

    @property
    def poles(self) -> tuple[int, ...]:
        return tuple(j for j, r in enumerate(self.roles) if r == "pole")

    @property
    def view_joint(self) -> int:
        """The joint the paper's controllers track: the first pole (else the actuated one)."""
        return self.poles[0] if self.poles else self.actuated

    def _roles(self, poles: tuple[str, ...]) -> tuple[str, ...]:
        names = self.joint_names
        hinges = [j.name for j in self.tree.joints if j.kind == "hinge"]
        for p in poles:
            if p not in names:
                raise ScenarioError(f"{self.where}: plant.poles: no joint named {p!r} (joints: "
                                    f"{', '.join(names)})")
            if p not in hinges:
                # the task watches only its poles for a fall: a slide cannot fall, and a
                # pole that cannot fall leaves the real ones unwatched
                raise ScenarioError(f"{self.where}: plant.poles: {p!r} is a slide joint, and a "
                                    f"pole must be a hinge that can fall (hinges: "
                                    f"{', '.join(hinges) or 'none'})")
        rng = np.random.default_rng(0)
        roles = []
        g = np.asarray(self.tree.gravity, dtype=float)
        for j, jf in enumerate(self.tree.joints):
            if poles:
                roles.append("pole" if jf.name in poles else
                             ("cart" if jf.kind == "slide" else self._free_role(j, g)))
                continue
            if jf.kind == "slide":
                roles.append("cart")
                continue
            works = False
            for _ in range(8):
                q = rng.uniform(-math.pi, math.pi, self.nv)
                if abs(self.gravity_torque(q)[j]) > 1e-9:
                    works = True
                    break
            roles.append("pole" if works else self._free_role(j, g))
        self._refuse_slides_on_poles(roles)
        return tuple(roles)

    def _refuse_slides_on_poles(self, roles: list[str]) -> None:
        """A slide carried by a pole (on its link or one beyond) is a link of the pendulum,
        read as a pole by the task and the documented machine, and a pole must be a hinge:
        refused here, naming it (read as a ``cart`` it would slide unwatched, and the
        design would fail later naming other joints)."""
        names = self.joint_names
        for j, joint in enumerate(self.tree.joints):
            if joint.kind != "slide":
                continue
            carrier = self._carrying_pole(j, roles)
            if carrier is not None:
                raise ScenarioError(f"{self.where}: joint {names[j]!r} is a slide carried by "
                                    f"the pole {names[carrier]!r}: a joint on a pole's link "
                                    f"is a pole, and a pole must be a hinge (a slide cannot "
                                    f"fall); make {names[j]!r} a hinge")

    def _carrying_pole(self, j: int, roles: list[str]) -> int | None:
        """The nearest pole that moves joint ``j``: an earlier joint of its body (MuJoCo
        applies a body's joints in order), else one of an ancestor body; None if none."""
        bodies = self.tree.bodies
        b = self.tree.joints[j].body
        earlier = [k for k in bodies[b].joints if k < j]
        while True:
            for k in reversed(earlier):
                if roles[k] == "pole":
                    return k
            b = bodies[b].parent
            if b < 0:
                return None
            earlier = list(bodies[b].joints)

    def _free_role(self, j: int, g: np.ndarray) -> str:
        import mujoco

        data = mujoco.MjData(self.model)
        mujoco.mj_kinematics(self.model, data)
        jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, self.joint_names[j])
        axis = np.asarray(data.xaxis[jid])
        gn = np.linalg.norm(g)
        if gn > 0 and abs(abs(float(axis @ g)) / gn - 1.0) < 1e-9:
            return "arm"
        return "rotor"

    # -- equations --------------------------------------------------------------------
    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Gravity's generalised force -dV_g/dq at ``q``, from the compiled equations (3)
        at rest with the springs, dampers and actuators' terms set to 0."""
        p = self.p.copy()
        for i, name in enumerate(self.parameter_names):
            if name.rsplit(".", 1)[-1] in ("stiffness", "damping", "gear"):
                p[i] = 0.0
        nv = self.nv
        M, r = np.zeros(nv * nv), np.zeros(nv)
        self.module.dynamics(np.asarray(q, dtype=float), np.zeros(nv),
                                  np.zeros(len(self.tree.actuators)), np.zeros(nv), p, M, r)
        return r

    def rhs_into(self, s: np.ndarray, u: float, d: float, d_joint: int, sdot: np.ndarray) -> None:
        """``s' = f(s, u)`` of equations (3), with the clips, ``d`` a generalised force on
        joint ``d_joint``."""
        self._qfrc[:] = 0.0
        self._qfrc[d_joint] = d
        self.rhs_forced(s, u, self._qfrc, sdot)

    def rhs_forced(self, s: np.ndarray, u: float, qfrc: np.ndarray, sdot: np.ndarray) -> None:
        """``s' = f(s, u)`` of equations (3), with the clips, the generalised forces
        ``qfrc`` on the joints."""
        self._u[:] = 0.0
        self._u[self.actuator_index] = u
        self.module.rhs(s, self._u, qfrc, self.p, self._M, self._r, sdot)

    def accelerations(self, s: np.ndarray, u: float) -> np.ndarray:
        sdot = np.empty(2 * self.nv)
        self.rhs_into(np.ascontiguousarray(s, dtype=float), u, 0.0, 0, sdot)
        return sdot[self.nv:].copy()

    def energy(self, s: np.ndarray) -> float:
        """``T + V`` less its value upright at rest (0 there)."""
        nv = self.nv
        T, V = self.derivation.energy(s[:nv], s[nv:], self.p)
        _, V0 = self.derivation.energy(np.zeros(nv), np.zeros(nv), self.p)
        return float(T) + float(V) - float(V0)

    def symbolic_accel(self, s: Any, u: Any, clips: bool = False) -> Any:
        """``q''`` over CasADi (``clips``: MuJoCo's ctrl and force clips applied; by default
        none, an optimiser bounds u itself)."""
        import casadi as ca

        nv, nu = self.nv, len(self.tree.actuators)
        uvec = ca.vertcat(*[u if k == self.actuator_index else 0.0 for k in range(nu)])
        fn = self.derivation.dynamics if clips else self.derivation.dynamics_free
        M, r = fn(s[:nv], s[nv:], uvec, ca.DM.zeros(nv), self.p)
        return ca.solve(ca.reshape(M, nv, nv), r)

    def casadi_f(self, clips: bool = False) -> Any:
        """``f(s, u, p) -> s'`` as a CasADi Function over SX: ``s = [q, q']`` (the joints'
        names, :attr:`state_names`), ``u`` every actuator's input (the model's order),
        ``p`` the parameter vector (:attr:`parameter_names`, nominal values :attr:`p`),
        differentiable in all three (``clips``: MuJoCo's ctrl and force clips applied,
        not smooth).  What identification and a randomised design use without deriving
        again."""
        import casadi as ca

        nv, nu = self.nv, len(self.tree.actuators)
        s, u = ca.SX.sym("s", 2 * nv), ca.SX.sym("u", nu)
        p = ca.SX.sym("p", self.p.size)
        fn = self.derivation.dynamics if clips else self.derivation.dynamics_free
        M, r = fn(s[:nv], s[nv:], u, ca.SX.zeros(nv), p)
        qdd = ca.solve(ca.reshape(M, nv, nv), r)
        return ca.Function("articulated_f", [s, u, p], [ca.vertcat(s[nv:], qdd)],
                           ["s", "u", "p"], ["sdot"])

    def linearisation(self, s_op: np.ndarray | None = None, u_op: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The exact ``(A, B)`` of ``s' = f(s, u)`` at ``(s_op, u_op)`` (default: upright at
        rest), by CasADi's differentiation of the derived equations."""
        import casadi as ca

        n = 2 * self.nv
        s, u = ca.SX.sym("s", n), ca.SX.sym("u")
        f = ca.vertcat(s[self.nv:], self.symbolic_accel(s, u))
        J = ca.Function("J", [s, u], [ca.jacobian(f, s), ca.jacobian(f, u)])
        s0 = np.zeros(n) if s_op is None else np.asarray(s_op, dtype=float)
        A, B = J(s0, u_op)
        return np.asarray(A, dtype=float), np.asarray(B, dtype=float).reshape(n, 1)

    def parameters(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.parameter_names, self.p)}


def load_machine(path: str | Path, timestep: float = 0.0, actuator: str = "",
                 poles: tuple[str, ...] = (), values: tuple[tuple[str, float], ...] = (),
                 integrator: str = "") -> Machine:
    """The MJCF at ``path`` compiled (:func:`open_spec` with ``timestep`` and ``integrator``;
    ``values``, ``(BODY.mass | JOINT.damping | JOINT.armature, value)`` pairs, written into
    it first: :mod:`.model_numbers`) and read."""
    from tspend.plants.articulated.model_numbers import compile_with_values

    spec = open_spec(path, timestep, integrator)
    return Machine(compile_with_values(spec, values, str(path)), str(path), actuator, poles)


def open_spec(path: str | Path, timestep: float | None = 0.0, integrator: str = "") -> Any:
    """The MJCF at ``path`` read within the size bounds (:func:`tspend.runtime.model_file.read_spec`)
    with ``timestep`` (> 0; 0 or None keeps the model's) and MuJoCo's ``integrator`` ("RK4",
    "Euler", "implicit", "implicitfast"; "" keeps the model's) written in: how every MuJoCo
    machine's file comes in (``plant.timestep``, ``plant.integrator``)."""
    from tspend.runtime.model_file import read_spec

    where = str(path)
    if not Path(path).is_file():
        raise ScenarioError(f"{where}: model file not found")
    spec = read_spec(where)
    if timestep:
        if not (timestep > 0.0 and math.isfinite(timestep)):
            raise ScenarioError(f"{where}: timestep must be positive, got {timestep}")
        spec.option.timestep = float(timestep)
    if integrator:
        by_name = {v: k for k, v in INTEGRATOR_NAMES.items()}
        if integrator not in by_name:
            raise ScenarioError(f"{where}: unknown integrator {integrator!r} (allowed: "
                                f"{', '.join(by_name)})")
        spec.option.integrator = by_name[integrator]
    return spec
