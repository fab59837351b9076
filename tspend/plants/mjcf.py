"""Any MJCF cart-pole read as it is, and M, m, l, J written so the compiled model has them.

:func:`read_facts` measures, from the *compiled* model, everything the paper's ODE
assumes: the cart and pole masses, the pivot-to-COM distance, the pole's inertia about
the hinge, the actuator's gear and clipping, joint damping, friction loss, armature and
limits, the integrator and timestep, contacts, and the sign of d(theta'')/du at the
upright.  :func:`departures` turns them into one-line statements of how the model
departs from the ideal ODE (``tspend inspect`` prints them; a run warns with them).

:func:`apply_overrides` writes M, m, l (and J, the uniform rod's by default) into an
``MjSpec`` whatever the compiler settings are: the pole's and cart's geoms stop
contributing mass and the two bodies get explicit inertials; :func:`verify_overrides`
then reads the compiled model back and names the body that did not take a value.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import mujoco
import numpy as np

from tspend.errors import ScenarioError
from tspend.plants.cartpole_physics import CartPoleParams

#: MuJoCo integrators by their MJCF names
INTEGRATOR_NAMES = {mujoco.mjtIntegrator.mjINT_RK4: "RK4", mujoco.mjtIntegrator.mjINT_EULER: "Euler",
                    mujoco.mjtIntegrator.mjINT_IMPLICIT: "implicit",
                    mujoco.mjtIntegrator.mjINT_IMPLICITFAST: "implicitfast"}

# Axial inertia of the rod relative to its transverse one: never enters the planar
# dynamics but must be positive; reproduces models/cartpole.xml's 1e-4 kg m^2.
AXIAL_INERTIA_RATIO = 1.0 / 3e4

#: relative mismatch tolerated between a requested and a compiled parameter
VERIFY_RTOL = 1e-9


@dataclass(frozen=True)
class JointFacts:
    name: str
    damping: float
    frictionloss: float
    armature: float
    stiffness: float
    limited: bool
    range: tuple[float, float]


@dataclass(frozen=True)
class ModelFacts:
    """What a compiled MJCF cart-pole holds (SI units; angles in rad)."""

    path: str
    cart_mass: float                 #: everything the slider carries but the pole
    pole_mass: float                 #: the hinge body's subtree
    pole_com: float                  #: distance hinge axis -> pole COM
    pole_inertia_pivot: float        #: about the hinge axis
    rod_inertia_pivot: float         #: 4/3 m l^2, what the ODE assumes
    gain_sign: int                   #: sign of d(theta'')/du at the upright, at rest
    theta_sign: int                  #: +1: theta > 0 leans the pole away from the slide axis
    gear: float
    ctrl_limited: bool
    ctrl_range: tuple[float, float] | None
    force_limited: bool
    force_range: tuple[float, float] | None
    actuator_type: str               #: "motor" when gain is fixed and there is no bias
    slide: JointFacts
    hinge: JointFacts
    timestep: float
    integrator: str
    contacts: bool
    gravity: float                   #: downward component, m/s^2
    departures: tuple[str, ...] = field(default=())

    def params(self) -> CartPoleParams:
        """The ODE of this very machine (armature counts as mass and inertia)."""
        return CartPoleParams(
            M=self.cart_mass + self.slide.armature, m=self.pole_mass, l=self.pole_com,
            g=self.gravity, J=self.pole_inertia_pivot + self.hinge.armature,
            cart_damping=self.slide.damping, hinge_damping=self.hinge.damping,
            cart_friction=self.slide.frictionloss, hinge_friction=self.hinge.frictionloss,
            gear=self.gear, theta_sign=float(self.theta_sign))

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["departures"] = list(self.departures)
        return d


def _joint(model: mujoco.MjModel, j: int) -> JointFacts:
    dof = int(model.jnt_dofadr[j])
    return JointFacts(name=model.joint(j).name, damping=float(model.dof_damping[dof]),
                      frictionloss=float(model.dof_frictionloss[dof]),
                      armature=float(model.dof_armature[dof]),
                      stiffness=float(model.jnt_stiffness[j]),
                      limited=bool(model.jnt_limited[j]),
                      range=(float(model.jnt_range[j][0]), float(model.jnt_range[j][1])))


def subtree(model: mujoco.MjModel, root: int) -> list[int]:
    return [b for b in range(model.nbody)
            if b == root or _is_below(model, b, root)]


def _is_below(model: mujoco.MjModel, b: int, root: int) -> bool:
    while b > 0:
        b = int(model.body_parentid[b])
        if b == root:
            return True
    return False


def pole_inertials(model: mujoco.MjModel, data: mujoco.MjData, hinge: int
                   ) -> tuple[float, float, float, np.ndarray]:
    """Mass, COM distance from the hinge axis, inertia about it, and the axis-normal COM arm.

    Summed over the hinge body's subtree at the model's reference pose (kinematics of
    ``data`` must be current).
    """
    pole = int(model.jnt_bodyid[hinge])
    axis, anchor = data.xaxis[hinge].copy(), data.xanchor[hinge].copy()
    mass, moment, inertia = 0.0, np.zeros(3), 0.0
    for b in subtree(model, pole):
        mb = float(model.body_mass[b])
        r = data.xipos[b] - anchor
        R = data.ximat[b].reshape(3, 3)
        a_local = R.T @ axis
        inertia += float(a_local @ (model.body_inertia[b] * a_local)) + mb * float(
            np.linalg.norm(np.cross(axis, r)) ** 2)
        mass += mb
        moment += mb * r
    com = moment / mass if mass > 0.0 else np.zeros(3)
    arm = com - float(com @ axis) * axis
    return mass, float(np.linalg.norm(arm)), inertia, arm


def read_facts(model: mujoco.MjModel, slide_joint: str, hinge_joint: str, actuator: str,
               path: str = "") -> ModelFacts:
    """Measure the compiled ``model`` (joint and actuator names already checked)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    s, h = model.joint(slide_joint).id, model.joint(hinge_joint).id
    a = model.actuator(actuator).id
    cart = int(model.jnt_bodyid[s])
    m, l, J, arm = pole_inertials(model, data, h)
    M = float(model.body_subtreemass[cart]) - m
    slide_axis = data.xaxis[s].copy()
    # positive rotation moves the COM by axis x arm; the paper's theta > 0 leans to -x
    lean = float(np.cross(data.xaxis[h], arm) @ slide_axis)
    theta_sign = 1 if lean <= 0.0 else -1

    gear = float(model.actuator_gear[a][0])
    ctrl_limited = bool(model.actuator_ctrllimited[a])
    force_limited = bool(model.actuator_forcelimited[a])
    motor = (int(model.actuator_gaintype[a]) == mujoco.mjtGain.mjGAIN_FIXED
             and int(model.actuator_biastype[a]) == mujoco.mjtBias.mjBIAS_NONE
             and int(model.actuator_dyntype[a]) == mujoco.mjtDyn.mjDYN_NONE)
    gain = float(model.actuator_gainprm[a][0])
    probe = 1e-3
    if ctrl_limited:
        lo, hi = model.actuator_ctrlrange[a]
        probe = min(probe, 0.5 * float(hi)) if hi > 0 else probe
    g = -float(model.opt.gravity[2])

    # the sign of Assumption 5, measured: theta'' at the upright for a small push
    dof = int(model.jnt_dofadr[h])
    data.qpos[:] = model.qpos0
    data.qvel[:] = 0.0
    data.ctrl[:] = 0.0
    mujoco.mj_forward(model, data)
    base = float(data.qacc[dof])
    data.ctrl[a] = probe
    mujoco.mj_forward(model, data)
    gain_sign = 1 if float(data.qacc[dof]) - base >= 0.0 else -1

    facts = ModelFacts(
        path=path, cart_mass=M, pole_mass=m, pole_com=l, pole_inertia_pivot=J,
        rod_inertia_pivot=4.0 / 3.0 * m * l * l, gain_sign=gain_sign, theta_sign=theta_sign,
        gear=gear * gain if motor else gear, ctrl_limited=ctrl_limited,
        ctrl_range=tuple(float(v) for v in model.actuator_ctrlrange[a]) if ctrl_limited else None,
        force_limited=force_limited,
        force_range=tuple(float(v) for v in model.actuator_forcerange[a]) if force_limited else None,
        actuator_type="motor" if motor else "other",
        slide=_joint(model, s), hinge=_joint(model, h), timestep=float(model.opt.timestep),
        integrator=INTEGRATOR_NAMES.get(model.opt.integrator, str(int(model.opt.integrator))),
        contacts=not (model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT)
        and model.ngeom > 0 and _has_colliders(model), gravity=g)
    return _with_departures(facts)


def _has_colliders(model: mujoco.MjModel) -> bool:
    return bool(np.any((model.geom_contype != 0) | (model.geom_conaffinity != 0)))


def _with_departures(f: ModelFacts) -> ModelFacts:
    from dataclasses import replace

    return replace(f, departures=tuple(departures(f)))


#: a cart force bound (N) at or above this is beyond every paper case's need (733 N at
#: most, measured in models/cartpole.xml's comment): not reported as a departure
UNREACHED_FORCE = 1000.0


def departures(f: ModelFacts, dt: float | None = None) -> list[str]:
    """How the model departs from the paper's ideal cart-pole ODE, one line each."""
    out: list[str] = []
    if abs(f.pole_inertia_pivot - f.rod_inertia_pivot) > 1e-6 * max(f.rod_inertia_pivot, 1e-12):
        out.append(f"pole inertia about the pivot is {f.pole_inertia_pivot:.6g} kg m^2, not the "
                   f"uniform rod's 4/3 m l^2 = {f.rod_inertia_pivot:.6g}")
    if f.gain_sign < 0:
        out.append("reversed gain sign: u > 0 gives theta'' < 0 at the upright (the paper "
                   "controller takes this sign from the model unless controller.gain_sign "
                   "says otherwise)")
    if f.actuator_type != "motor":
        out.append("actuator is not a plain motor (gain, bias or dynamics): u is not a force")
    if f.gear != 1.0:
        out.append(f"actuator gear {f.gear:g}: the cart force is {f.gear:g} u")
    force_max = abs(f.gear) * max(map(abs, f.ctrl_range)) if f.ctrl_range is not None else 0.0
    # a motor limit no paper case reaches (they need at most 733 N; models/cartpole.xml's
    # 2000 N) changes none of them: not a departure worth a warning on every run
    if f.ctrl_limited and f.ctrl_range is not None and force_max < UNREACHED_FORCE:
        out.append(f"clipped actuator: ctrlrange [{f.ctrl_range[0]:g}, {f.ctrl_range[1]:g}] "
                   f"(force at most {abs(f.gear) * max(map(abs, f.ctrl_range)):g} N)")
    if f.force_limited and f.force_range is not None:
        out.append(f"clipped actuator: forcerange [{f.force_range[0]:g}, {f.force_range[1]:g}] N")
    for label, j in (("slide", f.slide), ("hinge", f.hinge)):
        if j.damping:
            out.append(f"{label} joint '{j.name}' has damping {j.damping:g}")
        if j.frictionloss:
            out.append(f"{label} joint '{j.name}' has dry friction (frictionloss) {j.frictionloss:g}")
        if j.armature:
            out.append(f"{label} joint '{j.name}' has armature {j.armature:g}")
        if j.stiffness:
            out.append(f"{label} joint '{j.name}' has stiffness {j.stiffness:g}")
        if j.limited:
            out.append(f"{label} joint '{j.name}' is limited to [{j.range[0]:g}, {j.range[1]:g}]")
    if f.integrator != "RK4":
        out.append(f"integrator {f.integrator}, not RK4: MuJoCo and the ODE differ by its "
                   f"truncation error (plant.integrator = \"RK4\" to match)")
    if f.contacts:
        out.append("contacts are enabled and some geoms collide")
    if dt is not None:
        k = dt / f.timestep
        if abs(k - round(k)) > 1e-9 * max(k, 1.0) or round(k) < 1:
            out.append(f"timestep {f.timestep:g} s does not divide dt = {dt:g} s "
                       f"(set plant.timestep)")
        elif round(k) > 1:
            out.append(f"timestep {f.timestep:g} s: {round(k)} physics steps per control "
                       f"sample (dt = {dt:g} s)")
    return out


# -- overrides ---------------------------------------------------------------------------
def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0.0 else np.array([0.0, 0.0, 1.0])


def apply_overrides(spec: mujoco.MjSpec, cart: Any, hinge: Any, p: CartPoleParams,
                    where: str) -> None:
    """Write M, m, l, J and g into ``spec`` so that the compiled model has them.

    The pole body gets an explicit inertial: mass m, COM at l along the pole, the
    transverse inertia that makes J about the pivot (the rod's m (2l)^2/12 by default);
    the cart body gets the mass that makes everything the slider carries but the pole
    equal M.  Both bodies' geoms stop contributing mass, so ``inertiafromgeom`` cannot
    undo this.  The pole body must not have child bodies (their masses would be the
    pole's too): then the error names it.
    """
    for name in ("M", "m", "l", "g"):
        v = getattr(p, name)
        if not (math.isfinite(v) and v > 0.0):
            raise ScenarioError(f"{where}: cart-pole parameter {name} must be positive, got {v}")
    pole = hinge.parent
    if list(pole.bodies):
        raise ScenarioError(f"{where}: cannot set m, l on body '{pole.name}': it has child "
                            f"bodies ({', '.join(b.name or '<unnamed>' for b in pole.bodies)}) "
                            f"whose masses the pole would also carry")
    pivot = np.asarray(hinge.pos, dtype=float)
    axis = _pole_direction(pole, pivot)
    J = p.pole_inertia_pivot
    i_perp = J - p.m * p.l ** 2
    if i_perp <= 0.0:
        raise ScenarioError(f"{where}: pole inertia about the pivot J = {J:g} must exceed "
                            f"m l^2 = {p.m * p.l ** 2:g} (body '{pole.name}')")
    _massless_geoms(pole)
    pole.explicitinertial = True
    pole.mass = p.m
    pole.ipos = pivot + p.l * axis
    pole.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
    pole.inertia = [i_perp, i_perp, i_perp * AXIAL_INERTIA_RATIO]
    iquat = np.zeros(4)
    mujoco.mju_quatZ2Vec(iquat, axis)
    pole.iquat = iquat

    others = [b for b in _descendants(cart) if b is not pole]
    carried = sum(float(b.mass) for b in others)
    cart_mass = p.M - carried
    if cart_mass <= 0.0:
        raise ScenarioError(f"{where}: cannot set M = {p.M:g} on body '{cart.name}': the "
                            f"bodies it carries besides the pole already weigh {carried:g} kg")
    scale = cart_mass / float(cart.mass) if float(cart.mass) > 0.0 else 1.0
    inertia = np.asarray(cart.inertia, dtype=float) * scale
    _massless_geoms(cart)
    cart.explicitinertial = True
    cart.mass = cart_mass
    cart.fullinertia = [math.nan, 0.0, 0.0, 0.0, 0.0, 0.0]
    cart.inertia = inertia if np.all(inertia > 0.0) else [1.0, 1.0, 1.0]
    spec.option.gravity = [0.0, 0.0, -p.g]
    # explicit inertials win over geoms only when the compiler is told to use them
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO


def _pole_direction(pole: Any, pivot: np.ndarray) -> np.ndarray:
    """Where the pole points in its body frame: toward its COM, else its longest geom, else z."""
    arm = np.asarray(pole.ipos, dtype=float) - pivot
    if float(np.linalg.norm(arm)) > 1e-9:
        return _unit(arm)
    for geom in pole.geoms:
        fromto = np.asarray(geom.fromto, dtype=float)
        if not math.isnan(fromto[0]):
            a, b = fromto[:3] - pivot, fromto[3:] - pivot
            far = b if np.linalg.norm(b) >= np.linalg.norm(a) else a
            if np.linalg.norm(far) > 1e-9:
                return _unit(far)
        pos = np.asarray(geom.pos, dtype=float) - pivot
        if np.linalg.norm(pos) > 1e-9:
            return _unit(pos)
    return np.array([0.0, 0.0, 1.0])


def _massless_geoms(body: Any) -> None:
    for geom in body.geoms:
        geom.mass = 0.0
        geom.density = 0.0


def _descendants(body: Any) -> list[Any]:
    out = []
    for child in body.bodies:
        out.append(child)
        out.extend(_descendants(child))
    return out


def verify_overrides(facts: ModelFacts, p: CartPoleParams, cart: str, pole: str,
                     where: str) -> None:
    """The compiled model must hold the requested M, m, l, J: else name the body and why."""
    checks = (("M", facts.cart_mass, p.M, cart), ("m", facts.pole_mass, p.m, pole),
              ("l", facts.pole_com, p.l, pole), ("J", facts.pole_inertia_pivot,
                                                  p.pole_inertia_pivot, pole),
              ("g", facts.gravity, p.g, "option"))
    for name, got, want, body in checks:
        if abs(got - want) > VERIFY_RTOL * max(abs(want), 1.0):
            raise ScenarioError(f"{where}: {name} = {want:g} did not take effect on body "
                                f"'{body}': the compiled model has {got:.9g} (check the "
                                f"compiler's settotalmass, boundmass or a frame around it)")


def read_spec(path: "str | os.PathLike[str]") -> "mujoco.MjSpec":
    """Parse an MJCF file within the size bounds (docs/reliability.md): the file size is
    checked before MuJoCo reads it, the heightfields and bodies before it compiles.

    Raises
    ------
    ScenarioError
        no such file, larger than :data:`~tspend.runtime.bounds.MAX_MODEL_BYTES`, not
        parseable, a heightfield of more than ``MAX_HFIELD_CELLS`` cells, or more than
        ``MAX_BODIES`` bodies.
    """
    import os

    from tspend.runtime.bounds import MAX_BODIES, MAX_HFIELD_CELLS, MAX_MODEL_BYTES

    import stat

    where = str(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        raise ScenarioError(f"{where}: model file not found") from None
    if not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{where}: not a regular file (an MJCF model file is expected)")
    size = st.st_size
    if size > MAX_MODEL_BYTES:
        raise ScenarioError(f"{where}: the model file is {size} bytes, more than "
                            f"{MAX_MODEL_BYTES}")
    _check_xml_sizes(path, where)  # MuJoCo allocates a heightfield as it parses
    try:
        spec = mujoco.MjSpec.from_file(where)
    except (ValueError, OSError) as exc:
        raise ScenarioError(f"{where}: cannot parse MJCF: {' '.join(str(exc).split())}") \
            from None
    for hfield in spec.hfields:
        cells = int(hfield.nrow) * int(hfield.ncol)
        if cells > MAX_HFIELD_CELLS:
            raise ScenarioError(f"{where}: heightfield {hfield.name!r} has {hfield.nrow} x "
                                f"{hfield.ncol} = {cells} cells, more than {MAX_HFIELD_CELLS}")
    bodies = len(spec.bodies)
    if bodies > MAX_BODIES:
        raise ScenarioError(f"{where}: {bodies} bodies, more than {MAX_BODIES}")
    return spec


def _check_xml_sizes(path: "str | os.PathLike[str]", where: str, depth: int = 0) -> None:
    """The sizes MuJoCo would allocate as it parses, read from the XML text first: each
    heightfield's ``nrow`` x ``ncol``, the bodies, and the same in included files."""
    import os
    import xml.etree.ElementTree as ET

    from tspend.runtime.bounds import MAX_BODIES, MAX_HFIELD_CELLS, MAX_MODEL_BYTES

    if depth > 8:
        raise ScenarioError(f"{where}: includes nested more than 8 deep")
    bodies = 0
    try:
        for _, element in ET.iterparse(os.fspath(path), events=("start",)):
            tag = element.tag
            if tag == "body":
                bodies += 1
                if bodies > MAX_BODIES:
                    raise ScenarioError(f"{where}: more than {MAX_BODIES} bodies")
            elif tag == "hfield":
                try:
                    nrow = int(element.get("nrow", "0"))
                    ncol = int(element.get("ncol", "0"))
                except ValueError:
                    continue  # MuJoCo reports it
                if nrow * ncol > MAX_HFIELD_CELLS:
                    raise ScenarioError(f"{where}: heightfield {element.get('name', '')!r} has "
                                        f"{nrow} x {ncol} = {nrow * ncol} cells, more than "
                                        f"{MAX_HFIELD_CELLS}")
            elif tag == "include" and element.get("file"):
                included = os.path.join(os.path.dirname(os.fspath(path)), element.get("file"))
                try:
                    size = os.stat(included).st_size
                except OSError:
                    continue  # MuJoCo reports it
                if size > MAX_MODEL_BYTES:
                    raise ScenarioError(f"{where}: included file {element.get('file')} is "
                                        f"{size} bytes, more than {MAX_MODEL_BYTES}")
                _check_xml_sizes(included, where, depth + 1)
    except ET.ParseError:
        return  # not XML: MuJoCo's parser says why
    except RecursionError:
        raise ScenarioError(f"{where}: XML nested too deeply") from None
