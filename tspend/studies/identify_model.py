"""Parametric models for identification: a machine's equations with chosen physical
parameters as inputs, their nominal values read from its MJCF, and how a fitted value is
written back into the MJCF.

A :class:`ParametricModel` is what :mod:`tspend.studies.identify` fits:

* ``names`` / ``nominal``: every parameter it can fit, with the MJCF's own value;
* ``rhs(s, u, d, p)``: ``s' = f(s, u, d; p)`` as CasADi expressions, built from the
  domain's one source of equations (:func:`tspend.studies.cartpole_greybox.accelerations_factory`
  handed a machine structure whose fields are expressions of ``p``; for the Furuta the
  derived equations of :mod:`tspend.plants.articulated`, ``p`` in their parameter vector);
* ``write(spec, values)``: the fitted values edited into an ``mujoco.MjSpec``, returning one
  line per change (the XML comments of the calibrated model);
* ``positions`` / ``state_names``: the measured coordinates and the state order.

Implemented for the cart-pole (``cartpole`` domain), the Furuta pendulum (``furuta``) and
any machine of the articulated domain (``articulated``: the double cart-pole and the
other hinge/slide chains), whose equations come from :meth:`Machine.casadi_f`'s derivation
with the named entries of its parameter vector (``link1.mass``, ``link1.ipos_z``,
``hinge1.damping`` ...) as inputs.  Every model also offers a *sensor offset* per measured
joint (``<joint>.offset``: the record reads ``q + offset``), which is no part of the
MJCF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["ParametricModel", "cartpole_model", "furuta_model", "articulated_model",
           "load_model", "OFFSET"]

#: the suffix of a sensor offset's name (``hinge1.offset``): a constant the sensor adds to
#: the joint's position (measured = true + offset)
OFFSET = ".offset"


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
    #: names a user may ask for that cannot be fitted, with the reason
    refused: dict = field(default_factory=dict)
    #: compile each segment's simulation to C (``tspend identify --jit``; kept in the
    #: derivation cache): ~20x faster evaluations for a compile of some 10-40 s per
    #: machine, parameter set and segment length
    jit: bool = False
    #: the segment functions built so far, by (parameters, fixed values, length, channels)
    compiled: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        # one sensor offset per measured joint, 0 in the model (a sensor's, not the MJCF's)
        extra = [f"{j}{OFFSET}" for j in self.state_names[: self.dof]
                 if f"{j}{OFFSET}" not in self.nominal]
        self.names = tuple(self.names) + tuple(extra)
        self.nominal = {**self.nominal, **{k: 0.0 for k in extra}}
        units = {f"{j}{OFFSET}": ("m" if any(c.endswith("_m") for c in cols) else "rad")
                 for j, cols in zip(self.state_names[: self.dof], self.position_columns)}
        self.meaning = {**self.meaning, **{
            k: f"sensor offset of {k[:-len(OFFSET)]} (measured - true), {units[k]}"
            for k in extra}}

    def offsets(self, p: dict) -> list:
        """Each measured position's sensor offset (an expression of ``p``, else its fixed or
        nominal value 0)."""
        v = {**self.fixed, **p}
        return [v.get(f"{j}{OFFSET}", 0.0) for j in self.state_names[: self.dof]]

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
        physical = {k: v for k, v in values.items() if not k.endswith(OFFSET)}
        changes = self._write(spec, physical)
        # a sensor offset is no part of the machine: named, not written
        changes += [f"{k} ({self.meaning[k]}): {v:.6g}: not a model parameter; subtract it "
                    f"from the measurements" for k, v in sorted(values.items()) if k.endswith(OFFSET)]
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

    from tspend.studies import cartpole_greybox as cp
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
    machine0 = cp.machine_of(base)
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


#: the articulated parameter vector's entries identify may fit, by suffix (the body's
#: frame offsets ``pos_*``, spring references, ranges and gravity are geometry or settings)
_ARTICULATED_FITTABLE = ("mass", "ipos_x", "ipos_y", "ipos_z", "inertia_1", "inertia_2",
                         "inertia_3", "armature", "damping", "stiffness", "gear", "gain0",
                         "bias1", "bias2")
_ARTICULATED_MEANING = {
    "mass": "mass of body {0}, kg", "ipos_x": "centre of mass of body {0}, x in its frame, m",
    "ipos_y": "centre of mass of body {0}, y in its frame, m",
    "ipos_z": "centre of mass of body {0}, z in its frame, m",
    "inertia_1": "principal inertia 1 of body {0} about its centre of mass, kg m^2",
    "inertia_2": "principal inertia 2 of body {0} about its centre of mass, kg m^2",
    "inertia_3": "principal inertia 3 of body {0} about its centre of mass, kg m^2",
    "armature": "armature of joint {0}", "damping": "viscous damping of joint {0}",
    "stiffness": "stiffness of joint {0}", "gear": "gear of actuator {0}",
    "gain0": "gain of actuator {0} (gainprm[0])", "bias1": "position bias of actuator {0} (biasprm[1])",
    "bias2": "velocity bias of actuator {0} (biasprm[2])"}
#: why MuJoCo's dry friction is refused (docs/identify.md)
FRICTIONLOSS_REFUSED = (
    "MuJoCo's frictionloss is a force of its constraint solver (soft, regularised by "
    "solreffriction/solimpfriction, bounded by the value), not a term of the derived "
    "equations (docs/articulated.md names it a departure): a smooth stand-in (tanh) would "
    "fit a number that is not MuJoCo's frictionloss")


def articulated_model(path: str) -> ParametricModel:
    """A machine of the articulated domain (any hinge/slide tree, docs/articulated.md): its
    parameter vector's physical entries (:data:`_ARTICULATED_FITTABLE`, named as
    :attr:`Machine.parameter_names`: ``link1.mass``, ``link1.ipos_z``, ``link1.inertia_2``,
    ``hinge1.damping``, ``motor.gear`` ...) as inputs of the derived equations (3) of
    :mod:`tspend.plants.articulated.derive`, with MuJoCo's ctrl and force clips; ``d`` is a
    generalised force on the tracked pole's joint, as the plants apply it."""
    import casadi

    from tspend.plants.articulated.machine import load_machine

    mach = load_machine(path)
    tree = mach.tree
    allp = list(mach.parameter_names)
    p0 = np.asarray(mach.p, dtype=float)
    names = tuple(n for n in allp if n.rsplit(".", 1)[-1] in _ARTICULATED_FITTABLE)
    nominal = {n: float(p0[allp.index(n)]) for n in names}
    meaning = {n: _ARTICULATED_MEANING[n.rsplit(".", 1)[-1]].format(n.rsplit(".", 1)[0])
               for n in names}
    slide_units = {"armature": ("kg", "kg m^2"), "damping": ("N s/m", "N m s/rad"),
                   "stiffness": ("N/m", "N m/rad")}
    for j in tree.joints:
        for k, (us, uh) in slide_units.items():
            meaning[f"{j.name}.{k}"] += ", " + (us if j.kind == "slide" else uh)
    nv = mach.nv
    nu = len(tree.actuators)
    d_joint = mach.view_joint
    dyn = mach.derivation.dynamics           # with MuJoCo's ctrl/force clips, as it applies them

    def rhs(s, u, d, p):
        pv = casadi.vertcat(*[p[n] if n in p else float(p0[i]) for i, n in enumerate(allp)])
        uv = casadi.vertcat(*[u if k == mach.actuator_index else 0.0 for k in range(nu)])
        qfrc = casadi.vertcat(*[d if k == d_joint else 0.0 for k in range(nv)])
        M, r = dyn(s[:nv], s[nv:], uv, qfrc, pv)
        return casadi.vertcat(s[nv:], casadi.solve(casadi.reshape(M, nv, nv), r))

    def write(spec, values):
        out = []
        for name in sorted(values):
            owner, kind = name.rsplit(".", 1)
            v = float(values[name])
            if kind == "mass":
                spec.body(owner).mass = v
            elif kind.startswith("ipos_"):
                ip = np.array(spec.body(owner).ipos, dtype=float)
                ip["xyz".index(kind[-1])] = v
                spec.body(owner).ipos = ip
            elif kind.startswith("inertia_"):
                b = spec.body(owner)
                if not np.isnan(b.fullinertia[0]):
                    raise ScenarioError(f"--out: body {owner!r} gives fullinertia; write its "
                                        f"principal inertia by hand ({name} = {v:.6g})")
                ii = np.array(b.inertia, dtype=float)
                ii[int(kind[-1]) - 1] = v
                b.inertia = ii
            elif kind in ("damping", "stiffness"):
                arr = np.array(getattr(spec.joint(owner), kind), dtype=float).ravel()
                arr = np.atleast_1d(arr)
                arr[0] = v
                setattr(spec.joint(owner), kind, arr if arr.size > 1 else v)
            elif kind == "armature":
                spec.joint(owner).armature = v
            elif kind == "gear":
                g = np.array(spec.actuator(owner).gear, dtype=float)
                g[0] = v
                spec.actuator(owner).gear = g
            elif kind in ("gain0", "bias1", "bias2"):
                attr = "gainprm" if kind.startswith("gain") else "biasprm"
                arr = np.array(getattr(spec.actuator(owner), attr), dtype=float)
                arr[int(kind[-1])] = v
                setattr(spec.actuator(owner), attr, arr)
            out.append(f"{name} ({meaning[name]}): {nominal[name]:.6g} -> {v:.6g}")
        # read back what MuJoCo compiled (a default or inertiafromgeom could override an edit)
        from tspend.plants.articulated.derive import parameter_table
        from tspend.plants.articulated.tree import read_tree

        try:
            compiled = spec.compile()
        except ValueError as exc:
            raise ScenarioError(f"the calibrated model does not compile: {exc} (a principal "
                                f"inertia alone may break the triangle inequality: give the "
                                f"other axes' with --fix)") from None
        got_names, got = parameter_table(read_tree(compiled))
        for name in values:
            g = float(got[list(got_names).index(name)])
            if not math.isclose(g, float(values[name]), rel_tol=1e-9, abs_tol=1e-12):
                raise ScenarioError(f"--out: {name} = {values[name]:.9g} written, but the "
                                    f"compiled model has {g:.9g}")
        return out

    refused = {f"{j.name}.frictionloss": FRICTIONLOSS_REFUSED for j in tree.joints}
    cols = []
    for j in tree.joints:
        unit = "m" if j.kind == "slide" else "rad"
        cols.append(((f"{j.name}_{unit}",), (f"{j.name}_dot_{unit}_s",)))
    unit_u = mach.input_unit.replace(" ", "_")
    return ParametricModel(
        domain="articulated", path=str(path), names=names, nominal=nominal, meaning=meaning,
        state_names=tuple(mach.state_names), position_columns=tuple(c[0] for c in cols),
        velocity_columns=tuple(c[1] for c in cols), input_columns=(f"u_{unit_u}", "u"),
        disturbance_columns=("d",), position_signs=(1.0,) * nv, _rhs=rhs, _write=write,
        timestep=float(mach.model.opt.timestep), refused=refused)


def load_model(path: str) -> ParametricModel:
    """The parametric model of the MJCF at ``path``, its domain recognised from its joints:
    a slide and a hinge -> the cart-pole; two hinges with a motor -> the Furuta; any other
    hinge/slide tree -> the articulated domain (its derived equations)."""
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
    return articulated_model(str(p))
