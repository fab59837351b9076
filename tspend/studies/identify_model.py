"""Parametric models for identification: a machine's equations with chosen physical
parameters as inputs, their nominal values read from its MJCF, and how a fitted value is
written back into the MJCF.

A :class:`ParametricModel` is what :mod:`tspend.studies.identify` fits:

* ``names`` / ``nominal``: every parameter it can fit, with the MJCF's own value;
* ``rhs(s, u, d, p)``: ``s' = f(s, u, d; p)`` as CasADi expressions, built from the
  domain's one source of equations (:func:`tspend.plants.cartpole_physics.accelerations_factory`
  handed a machine structure whose fields are expressions of ``p``; for the Furuta the
  derived equations of :mod:`tspend.plants.articulated`, ``p`` in their parameter vector);
* ``write(spec, values)``: the fitted values edited into an ``mujoco.MjSpec``, returning one
  line per change (the XML comments of the calibrated model);
* ``positions`` / ``state_names``: the measured coordinates and the state order.

Implemented for the cart-pole (``cartpole`` domain) and the Furuta pendulum (``furuta``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tspend.errors import ScenarioError

__all__ = ["ParametricModel", "cartpole_model", "furuta_model", "load_model"]


@dataclass
class ParametricModel:
    """One machine with named parameters (see the module docstring)."""

    domain: str
    path: str
    names: tuple[str, ...]
    nominal: dict[str, float]
    meaning: dict[str, str]
    #: state names in the order of ``rhs`` (positions first, then velocities)
    state_names: tuple[str, ...]
    #: the positions' column stems, per coordinate: candidates in the export
    position_columns: tuple[tuple[str, ...], ...]
    velocity_columns: tuple[tuple[str, ...], ...]
    input_columns: tuple[str, ...]
    disturbance_columns: tuple[str, ...]
    #: sign of the export's angle against the model's coordinate, per position
    position_signs: tuple[float, ...]
    _rhs: Callable[[Any, Any, Any, dict], Any] = field(repr=False, default=None)
    _write: Callable[[Any, dict], list[str]] = field(repr=False, default=None)
    timestep: float = 0.0
    #: parameters held at a known value other than the MJCF's (``--fix gear=1.08``)
    fixed: dict = field(default_factory=dict)

    @property
    def dof(self) -> int:
        return len(self.state_names) // 2

    def rhs(self, s, u, d, p: dict):
        """``s'`` (CasADi) with ``p`` mapping some parameter names to expressions (the
        rest at their nominal values)."""
        return self._rhs(s, u, d, {**self.fixed, **p})

    def write(self, values: dict[str, float], out: Path) -> list[str]:
        """A copy of the MJCF with ``values``: the list of changes, as written."""
        import mujoco

        spec = mujoco.MjSpec.from_file(self.path)
        changes = self._write(spec, values)
        try:
            spec.compile()
        except ValueError as exc:
            raise ScenarioError(f"the calibrated model does not compile: {exc}") from None
        xml = spec.to_xml()
        head = ("<!--\n  Calibrated by `tspend identify` from " + Path(self.path).name + ":\n"
                + "".join(f"    {c}\n" for c in changes) + "-->\n")
        from tspend.runtime.outputs import write_atomic
        text = head + xml
        write_atomic(out, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"),
                     what="calibrated model")
        return changes


def _casadi_clip(v, lo, hi):
    import casadi
    return casadi.fmin(casadi.fmax(v, lo), hi)


def cartpole_model(path: str, slide: str = "slider", hinge: str = "hinge",
                   actuator: str = "force") -> ParametricModel:
    """The cart-pole of the MJCF at ``path``: ``m`` (pole mass), ``l`` (pivot to the pole's
    COM; the inertia about the pivot scales as ``m l^2``), ``M`` (what the slider carries
    besides the pole), ``gear`` (force per unit u), ``cart_damping``, ``hinge_damping``."""
    import casadi
    import mujoco

    from tspend.plants import cartpole_physics as cp
    from tspend.plants import mjcf

    model = mujoco.MjModel.from_xml_path(path)
    facts = mjcf.read_facts(model, slide, hinge, actuator, path)
    base = facts.params()
    J_body = facts.pole_inertia_pivot
    J_arm = base.J - J_body
    nominal = {"m": base.m, "l": base.l, "M": base.M, "gear": base.gear,
               "cart_damping": base.cart_damping, "hinge_damping": base.hinge_damping}
    meaning = {"m": "pole mass, kg", "l": "hinge to pole COM, m", "M": "cart mass, kg",
               "gear": "actuator gear (force per unit u), N/u",
               "cart_damping": "slide joint damping, N s/m",
               "hinge_damping": "hinge joint damping, N m s/rad"}
    machine0 = base.machine()
    accel, _ = cp.accelerations_factory(casadi.sin, casadi.cos, casadi.tanh, clip=_casadi_clip)

    def rhs(s, u, d, p):
        v = {k: p.get(k, nominal[k]) for k in nominal}
        J = J_body * (v["m"] / nominal["m"]) * (v["l"] / nominal["l"]) ** 2 + J_arm
        mach = machine0._replace(M=v["M"], m=v["m"], l=v["l"], J=J, gear=v["gear"],
                                 cart_damping=v["cart_damping"],
                                 hinge_damping=v["hinge_damping"],
                                 disturbance_torque=-v["m"] * v["l"] / (v["M"] + v["m"]))
        qdd, xdd = accel(mach, s[0], s[2], s[1], s[3], u, d)
        return casadi.vertcat(s[2], s[3], qdd, xdd)

    def write(spec, values):
        out = []
        keys = frozenset(k for k in ("m", "l", "M") if k in values)
        if keys:
            v = {k: values.get(k, nominal[k]) for k in ("m", "l", "M")}
            J = J_body * (v["m"] / nominal["m"]) * (v["l"] / nominal["l"]) ** 2
            target = replace(base, M=v["M"], m=v["m"], l=v["l"], J=J)
            sj, hj = spec.joint(slide), spec.joint(hinge)
            mjcf.apply_overrides(spec, sj.parent, hj, target, path,
                                 keys | ({"J"} if keys & {"m", "l"} else set()))
            for k in sorted(keys):
                out.append(f"{k} ({meaning[k]}): {nominal[k]:.6g} -> {values[k]:.6g}")
            if keys & {"m", "l"}:
                out.append(f"pole inertia about the hinge (scaled as m l^2): "
                           f"{J_body:.6g} -> {J:.6g} kg m^2")
        if "gear" in values:
            act = spec.actuator(actuator)
            g = np.array(act.gear, dtype=float)
            g[0] = values["gear"]
            act.gear = g
            out.append(f"gear ({meaning['gear']}): {nominal['gear']:.6g} -> {values['gear']:.6g}")
        for k, j in (("cart_damping", slide), ("hinge_damping", hinge)):
            if k in values:
                spec.joint(j).damping = [values[k], 0.0, 0.0]
                out.append(f"{k} ({meaning[k]}): {nominal[k]:.6g} -> {values[k]:.6g}")
        return out

    return ParametricModel(
        domain="cartpole", path=str(path), names=tuple(nominal), nominal=nominal,
        meaning=meaning, state_names=("hinge", "slider", "hinge_dot", "slider_dot"),
        position_columns=(("theta_rad", f"{hinge}_rad"), ("cart_x_m", f"{slide}_m")),
        velocity_columns=(("theta_dot_rad_s", f"{hinge}_dot_rad_s"),
                          ("cart_v_m_s", f"{slide}_dot_m_s")),
        input_columns=("u_N", "u"), disturbance_columns=("d_N", "d"),
        position_signs=(base.theta_sign, 1.0), _rhs=rhs, _write=write,
        timestep=float(model.opt.timestep))


def furuta_model(path: str, arm: str = "arm", pendulum: str = "pendulum",
                 actuator: str = "motor") -> ParametricModel:
    """The Furuta pendulum of the MJCF at ``path``: ``arm_damping``, ``pendulum_damping``
    (joint damping), ``arm_armature``, ``pendulum_armature`` (kg m^2), ``motor_gain``
    (``gainprm[0]``, N m/V) and ``back_emf`` (``-biasprm[2]``, N m s/rad: the motor's
    torque falls by it per rad/s of the arm)."""
    import casadi
    import mujoco

    from tspend.plants.furuta import load_furuta

    model = mujoco.MjModel.from_xml_path(path)
    machine = load_furuta(path, arm, pendulum, actuator)
    da, dp = model.joint(arm).dofadr[0], model.joint(pendulum).dofadr[0]
    nominal = {"arm_damping": float(model.dof_damping[da]),
               "pendulum_damping": float(model.dof_damping[dp]),
               "arm_armature": float(model.dof_armature[da]),
               "pendulum_armature": float(model.dof_armature[dp]),
               "motor_gain": float(model.actuator_gainprm[model.actuator(actuator).id][0]),
               "back_emf": -float(model.actuator_biasprm[model.actuator(actuator).id][2])}
    meaning = {"arm_damping": "arm joint damping, N m s/rad",
               "pendulum_damping": "pendulum joint damping, N m s/rad",
               "arm_armature": "arm joint armature, kg m^2",
               "pendulum_armature": "pendulum joint armature, kg m^2",
               "motor_gain": "motor torque per volt (gainprm[0]), N m/V",
               "back_emf": "motor torque lost per arm rad/s (-biasprm[2]), N m s/rad"}
    # each parameter's place in the derived equations' parameter vector (docs/articulated.md)
    slot = {"arm_damping": f"{arm}.damping", "pendulum_damping": f"{pendulum}.damping",
            "arm_armature": f"{arm}.armature", "pendulum_armature": f"{pendulum}.armature",
            "motor_gain": f"{actuator}.gain0", "back_emf": f"{actuator}.bias2"}
    index = {name: i for i, name in enumerate(machine.parameter_names)}
    dynamics = machine.derivation.dynamics   # with MuJoCo's clips, as the plant steps

    def rhs(s, u, d, p):
        v = [float(x) for x in machine.p]
        for k, name in slot.items():
            if k in p:
                v[index[name]] = -p[k] if k == "back_emf" else p[k]
        M, r = dynamics(s[:2], s[2:], u, casadi.vertcat(0.0, d), casadi.vertcat(*v))
        qdd = casadi.solve(casadi.reshape(M, 2, 2), r)
        return casadi.vertcat(s[2], s[3], qdd[0], qdd[1])

    def write(spec, values):
        out = []
        for k, j, attr in (("arm_damping", arm, "damping"), ("pendulum_damping", pendulum, "damping"),
                           ("arm_armature", arm, "armature"),
                           ("pendulum_armature", pendulum, "armature")):
            if k in values:
                setattr(spec.joint(j), attr, [values[k], 0.0, 0.0] if attr == "damping" else values[k])
                out.append(f"{k} ({meaning[k]}): {nominal[k]:.6g} -> {values[k]:.6g}")
        act = spec.actuator(actuator)
        if "motor_gain" in values:
            g = np.array(act.gainprm, dtype=float)
            g[0] = values["motor_gain"]
            act.gainprm = g
            out.append(f"motor_gain ({meaning['motor_gain']}): {nominal['motor_gain']:.6g} -> "
                       f"{values['motor_gain']:.6g}")
        if "back_emf" in values:
            b = np.array(act.biasprm, dtype=float)
            b[2] = -values["back_emf"]
            act.biasprm = b
            out.append(f"back_emf ({meaning['back_emf']}): {nominal['back_emf']:.6g} -> "
                       f"{values['back_emf']:.6g}")
        return out

    return ParametricModel(
        domain="furuta", path=str(path), names=tuple(nominal), nominal=nominal, meaning=meaning,
        state_names=(arm, pendulum, f"{arm}_dot", f"{pendulum}_dot"),
        position_columns=(("arm_rad", f"{arm}_rad", "phi_rad"),
                          ("theta_rad", "alpha_rad", f"{pendulum}_rad")),
        velocity_columns=(("arm_dot_rad_s", f"{arm}_dot_rad_s", "phi_dot_rad_s"),
                          ("theta_dot_rad_s", "alpha_dot_rad_s", f"{pendulum}_dot_rad_s")),
        input_columns=("u_V", "u"), disturbance_columns=("d_N_m", "d"),
        position_signs=(1.0, 1.0), _rhs=rhs, _write=write, timestep=float(model.opt.timestep))


def load_model(path: str) -> ParametricModel:
    """The parametric model of the MJCF at ``path``, its domain recognised from its joints:
    a slide and a hinge -> the cart-pole; two hinges with a motor -> the Furuta."""
    import mujoco

    p = Path(path)
    if not p.is_file():
        raise ScenarioError(f"--model {path}: no such file")
    try:
        model = mujoco.MjModel.from_xml_path(str(p))
    except ValueError as exc:
        raise ScenarioError(f"--model {path}: cannot compile MJCF: {str(exc).splitlines()[0]}") from None
    types = [int(model.jnt_type[j]) for j in range(model.njnt)]
    names = [model.joint(j).name for j in range(model.njnt)]
    if model.nu != 1:
        raise ScenarioError(f"--model {path}: identification needs one actuator, the model has {model.nu}")
    act = model.actuator(0).name
    slide, hinge = mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE
    if types == [slide, hinge]:
        return cartpole_model(str(p), names[0], names[1], act)
    if types == [hinge, hinge]:
        return furuta_model(str(p), names[0], names[1], act)
    raise ScenarioError(f"--model {path}: joints {', '.join(names)}: identification supports "
                        f"the cart-pole (slide + hinge) and the Furuta (two hinges) for now")
