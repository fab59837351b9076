"""The cart-pole domain: everything the cart-pole means, for the rest of tspend.

Its equations of motion (C1)-(C2) are :mod:`tspend.plants.cartpole_physics` (written
once; compiled code and the MuJoCo backend import them from there); this module holds
the scenario's ``[plant]`` configuration of either backend, the analytic plant, the roles
of the MJCF's joints (``slide`` = the cart, ``hinge`` = the pole) and how each backend is
built, the model the baselines assume (the linearisation at the upright), labels and
units, the default task (view ``hinge``, ``hinge_dot``; fall angle pi/2) and the 3D drawing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

import numpy as np

from tspend.config import PlantConfig
from tspend.plants.analytic import COMPILED_RHS, AnalyticPlant, CompiledPlant
from tspend.plants.base import JointInfo, Plant, TaskDefaults, velocity_name
from tspend.plants.cartpole_physics import (DRY_FRICTION_SLIP, CartPoleMachine, CartPoleParams,
    accelerations, gain_sign, machine_accelerations, machine_rhs, rhs)
from tspend.plants.domain import Backend, Domain, Drawing, PlantLabels, PlantModel, Quantity

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["CartPoleParams", "CartPoleMachine", "CartPoleConfig", "MujocoCartPoleConfig",
           "CartPoleODE", "CartPoleDomain", "CartPoleDrawing", "DOMAIN", "DRY_FRICTION_SLIP",
           "accelerations", "gain_sign", "rhs", "machine_rhs", "machine_accelerations",
           "cartpole_ode_plant"]


# -- the scenario's [plant] table, on either backend -------------------------------------

def _positive(**more) -> dict:
    return {"low": 0.0, "strict": True, **more}


def _at_least_zero(**more) -> dict:
    return {"low": 0.0, **more}


@dataclass(frozen=True)
class CartPoleConfig(PlantConfig):
    """The cart-pole (C1)-(C2) of tspend/plants/cartpole.py, on either backend."""

    M: float = field(default=10.0, metadata=_positive())
    m: float = field(default=1.0, metadata=_positive())
    l: float = field(default=3.0, metadata=_positive())
    g: float = field(default=9.8, metadata=_at_least_zero())
    #: pole inertia about the pivot, kg m^2 (0 = the uniform rod's 4/3 m l^2)
    J: float = field(default=0.0, metadata=_at_least_zero())
    #: viscous damping (N s/m, N m s/rad) and dry friction (N, N m) at cart and hinge
    cart_damping: float = field(default=0.0, metadata=_at_least_zero())
    hinge_damping: float = field(default=0.0, metadata=_at_least_zero())
    cart_friction: float = field(default=0.0, metadata=_at_least_zero())
    hinge_friction: float = field(default=0.0, metadata=_at_least_zero())


@dataclass(frozen=True)
class MujocoCartPoleConfig(CartPoleConfig):
    """A cart-pole MJCF stepped by MuJoCo; M, m, l, J, g and friction are written into it."""

    #: model file (relative to the cwd, the scenario or the project root) and its names
    model: str = "models/cartpole.xml"
    slide_joint: str = "slider"
    hinge_joint: str = "hinge"
    actuator: str = "force"
    #: "" keeps the model's integrator
    integrator: str = field(default="", metadata={"choices": ("", "RK4", "Euler", "implicit",
                                                              "implicitfast")})
    #: physics timestep, s (0 keeps the model's); dt must be a whole multiple of it
    timestep: float = field(default=0.0, metadata=_at_least_zero())
    #: false keeps the model's own masses, COM and inertia (M, m, l, J are then ignored)
    override_inertials: bool = True



COMPILED_RHS[CartPoleMachine] = machine_rhs


# -- the analytic backend ---------------------------------------------------------------
class CartPoleODE(AnalyticPlant):
    """The cart-pole ODE (C1)-(C2), with the cart as hidden states, so the ODE backend can
    draw the cart and meet a finite rail too.  Its joints take the MJCF's names (and
    ranges) when it is built from a MuJoCo scenario (``slider``/``hinge`` by default).

    Integrated as ``s = [theta, theta', x_c, x_c']``; its full state is the MJCF's order,
    ``(slider, hinge, slider_dot, hinge_dot)``.
    """

    def __init__(self, params: CartPoleParams = CartPoleParams(), slide_joint: str = "slider",
                 hinge_joint: str = "hinge",
                 joint_ranges: dict[str, tuple[float, float]] | None = None) -> None:
        names = (slide_joint, hinge_joint, velocity_name(slide_joint), velocity_name(hinge_joint))
        super().__init__(lambda t, s, u, d: accelerations(self._machine, s[0], s[1], s[3], u, d)[0],
                         2, "cartpole_ode", hidden_names=("cart_pos", "cart_vel"),
                         domain="cartpole", state_names=names,
                         state_units=("m", "rad", "m/s", "rad/s"), full_order=(2, 0, 3, 1))
        self.slide_joint, self.hinge_joint = slide_joint, hinge_joint
        ranges = joint_ranges or {}
        self._joints = (JointInfo(slide_joint, "slide", "m", ranges.get(slide_joint)),
                        JointInfo(hinge_joint, "hinge", "rad", ranges.get(hinge_joint)))
        self.set_params(params)

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        return self._joints

    def default_task(self) -> TaskDefaults:
        """The cart-pole domain's task on this plant's joint names."""
        return DOMAIN.task.renamed({"slider": self.slide_joint, "hinge": self.hinge_joint,
                                    "slider_dot": velocity_name(self.slide_joint),
                                    "hinge_dot": velocity_name(self.hinge_joint)})

    @property
    def gain_sign(self) -> int:
        return int(gain_sign(self.params))

    def set_params(self, params: CartPoleParams) -> None:
        """Change the machine while it runs (a payload picked up); the state is kept."""
        self.params = params
        self._machine = params.machine()

    def parameters(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.params.__dict__.items()}

    def _rhs_params(self) -> Any:
        return self._machine

    def compiled(self) -> CompiledPlant:
        return CompiledPlant(self._machine, self.s, self._clock, self._work, self.full_order)


def cartpole_ode_plant(params: CartPoleParams = CartPoleParams(), slide_joint: str = "slider",
                       hinge_joint: str = "hinge",
                       joint_ranges: dict[str, tuple[float, float]] | None = None) -> CartPoleODE:
    return CartPoleODE(params, slide_joint, hinge_joint, joint_ranges)


def accel_fn(p: CartPoleParams) -> Callable[[float, np.ndarray, float, float], float]:
    """theta'' of (C1)-(C2) as ``f(t, x, u, d)`` over the view ``[theta, theta']``, with the
    cart at rest (its velocity enters only through cart damping)."""
    machine = p.machine()

    def accel(t: float, x: np.ndarray, u: float, d: float) -> float:
        return machine_accelerations(machine, x[0], x[1], 0.0, u, d)[0]

    return accel


def params_of(cfg: CartPoleConfig) -> CartPoleParams:
    """The machine a cart-pole configuration describes."""
    return CartPoleParams(M=cfg.M, m=cfg.m, l=cfg.l, g=cfg.g, J=cfg.J,
                          cart_damping=cfg.cart_damping, hinge_damping=cfg.hinge_damping,
                          cart_friction=cfg.cart_friction, hinge_friction=cfg.hinge_friction)


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    from tspend.plants.mujoco_plant import MujocoCartPole  # MuJoCo only when asked for

    assert isinstance(cfg, CartPoleConfig)
    mj = cfg if isinstance(cfg, MujocoCartPoleConfig) else MujocoCartPoleConfig(
        **{k: cfg.__dict__[k] for k in CartPoleConfig.__dataclass_fields__})
    friction = {k: (mj.__dict__[k] or None) for k in
                ("cart_damping", "hinge_damping", "cart_friction", "hinge_friction")}
    return MujocoCartPole(model_path, slide_joint=mj.slide_joint, hinge_joint=mj.hinge_joint,
                          actuator=mj.actuator,
                          overrides=params_of(mj) if mj.override_inertials else None,
                          integrator=mj.integrator or None, timestep=mj.timestep or None,
                          task_defaults=DOMAIN.task, **friction)


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, CartPoleConfig)
    if isinstance(cfg, MujocoCartPoleConfig):
        # the ODE of a MuJoCo scenario is the compiled model's (masses, inertia, damping,
        # gear and angle sign read back), so both backends describe one machine
        return DOMAIN.ode_of(_build_mujoco(cfg, model_path))
    return cartpole_ode_plant(params_of(cfg))


# -- labels, drawing, task, model -------------------------------------------------------
LABELS = PlantLabels(
    states=(Quantity("theta", "rad", "pole angle"),
            Quantity("theta'", "rad/s", "pole angular velocity")),
    control=Quantity("u", "N", "force on the cart"),
    extras={"cart_pos": Quantity("x_c", "m", "cart position"),
            "cart_vel": Quantity("x_c'", "m/s", "cart velocity")},
)

#: default cart box (x, y, z) in metres
CART_SIZE = (1.0, 0.6, 0.4)
POLE_RADIUS = 0.05
#: pole half-length used when the plant metadata does not give one
DEFAULT_POLE_HALF_LENGTH = 3.0
#: the drawn rail runs over [-RAIL_M, RAIL_M]: cart-poles drift tens of metres in a long run
RAIL_M = 100.0
#: a short tick every metre, a labelled mark every LABEL_EVERY_M (Rerun hides labels
#: of entities with more than ~30 instances, so the labels stay fewer than that)
LABEL_EVERY_M = 10.0
RAIL_COLOR = (90, 90, 90)

Color = tuple[int, int, int]


class CartPolePoses(NamedTuple):
    """World poses (z up) of the cart box centre and of the pole's centre of mass."""

    cart_translation: np.ndarray   # (N, 3)
    pole_translation: np.ndarray   # (N, 3), the pole's COM
    pole_quaternion: np.ndarray    # (N, 4), xyzw; rotates local +z onto the pole axis


def cartpole_poses(cart_pos: np.ndarray | float, theta: np.ndarray | float, l: float,
                   cart_height: float = CART_SIZE[2]) -> CartPolePoses:
    """Poses of cart and pole for cart positions ``cart_pos`` and pole angles ``theta``.

    x points right (the cart's rail), z up.  The cart box sits on z = 0; the pole's
    pivot is the centre of the box's top face; the pole (length ``2 l``) points along
    ``(-sin theta, 0, cos theta)``, so ``theta > 0`` leans it toward -x, and its centre
    of mass is ``l`` from the pivot.  Draw the pole as a capsule from local
    ``(0, 0, -l)`` to ``(0, 0, l)``.
    """
    xc = np.atleast_1d(np.asarray(cart_pos, dtype=np.float64))
    th = np.atleast_1d(np.asarray(theta, dtype=np.float64))
    xc, th = np.broadcast_arrays(xc, th)
    zeros = np.zeros_like(th)
    cart = np.column_stack([xc, zeros, np.full_like(th, 0.5 * cart_height)])
    pole = np.column_stack([xc - l * np.sin(th), zeros, cart_height + l * np.cos(th)])
    # rotation by -theta about +y maps +z onto (-sin theta, 0, cos theta)
    half = -0.5 * th
    quat = np.column_stack([zeros, np.sin(half), zeros, np.cos(half)])
    return CartPolePoses(cart, pole, quat)


@dataclass(frozen=True)
class CartPoleGeometry:
    """Sizes and colours of the drawn cart-pole."""

    l: float = DEFAULT_POLE_HALF_LENGTH
    cart_half_sizes: tuple[float, float, float] = (0.5 * CART_SIZE[0], 0.5 * CART_SIZE[1],
                                                   0.5 * CART_SIZE[2])
    cart_color: Color = (70, 110, 170)
    pole_radius: float = POLE_RADIUS
    pole_color: Color = (220, 140, 40)


def geometry_from_mjcf(path: str, base: CartPoleGeometry) -> CartPoleGeometry:
    """Cart = the box on the slider's body; pole = the longest capsule/cylinder on the
    hinge's body; colours as MuJoCo renders them.  Best effort: any failure keeps ``base``."""
    try:
        import mujoco

        from tspend.plants.mjcf import read_spec

        model = read_spec(path).compile()
    except Exception:  # noqa: BLE001 - drawing must never stop a run
        return base

    def body_of(joint_type: int) -> int | None:
        found = [int(model.jnt_bodyid[j]) for j in range(model.njnt)
                 if int(model.jnt_type[j]) == joint_type]
        return found[0] if found else None

    def color(g: int) -> Color:
        rgba = model.geom_rgba[g]
        if int(model.geom_matid[g]) >= 0 and np.allclose(rgba, (0.5, 0.5, 0.5, 1.0)):
            rgba = model.mat_rgba[int(model.geom_matid[g])]
        return tuple(int(round(255 * c)) for c in rgba[:3])  # type: ignore[return-value]

    cart_body = body_of(mujoco.mjtJoint.mjJNT_SLIDE)
    pole_body = body_of(mujoco.mjtJoint.mjJNT_HINGE)
    geoms = range(model.ngeom)
    boxes = [g for g in geoms if int(model.geom_bodyid[g]) == cart_body
             and int(model.geom_type[g]) == mujoco.mjtGeom.mjGEOM_BOX]
    rods = [g for g in geoms if int(model.geom_bodyid[g]) == pole_body
            and int(model.geom_type[g]) in (mujoco.mjtGeom.mjGEOM_CAPSULE,
                                            mujoco.mjtGeom.mjGEOM_CYLINDER)]
    geom = base
    if boxes:
        size = model.geom_size[boxes[0]]
        geom = replace(geom, cart_half_sizes=(float(size[0]), float(size[1]), float(size[2])),
                       cart_color=color(boxes[0]))
    if rods:
        rod = max(rods, key=lambda g: float(model.geom_size[g][1]))
        geom = replace(geom, pole_radius=float(model.geom_size[rod][0]), pole_color=color(rod))
    return geom


def readout_labels(cart_pos: np.ndarray) -> list[str]:
    """The text shown on the cart at each frame."""
    return [f"x_c = {x:+.2f} m" for x in np.asarray(cart_pos, dtype=np.float64)]


@dataclass(frozen=True)
class CartPoleDrawing(Drawing):
    """The cart-pole in 3D: the machine's parameters and, for MuJoCo, the MJCF whose geoms
    give sizes and colours.  ``theta_sign`` is -1 when the model's positive angle leans
    the pole toward +x (drawn as it moves)."""

    M: float
    m: float
    l: float
    g: float
    mjcf: str = ""
    theta_sign: float = 1.0
    title = "cart-pole"

    def geometry(self) -> CartPoleGeometry:
        geom = CartPoleGeometry(l=self.l)
        return geometry_from_mjcf(self.mjcf, geom) if self.mjcf else geom

    def document(self) -> dict[str, Any]:
        return {"M": self.M, "m": self.m, "l": self.l, "g": self.g, "mjcf": self.mjcf,
                "theta_sign": self.theta_sign}

    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        """Ground frame, cart and pole shapes, the rail with distance marks, the readout."""
        import rerun as rr

        geom = self.geometry()
        rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(f"{world}/cart", rr.Boxes3D(half_sizes=[geom.cart_half_sizes],
                                            colors=[shade(geom.cart_color)],
                                            fill_mode=rr.components.FillMode.Solid), static=True)
        rec.log(f"{world}/cart/readout", rr.Points3D(
            [[0.0, -geom.cart_half_sizes[1] - 1.0, 0.0]], radii=[0.01], colors=[(40, 40, 40)],
            show_labels=True), static=True)
        rec.log(f"{world}/pole", rr.Capsules3D(
            lengths=[2.0 * geom.l], radii=[geom.pole_radius], translations=[[0.0, 0.0, -geom.l]],
            colors=[shade(geom.pole_color)]), static=True)
        half_width = geom.cart_half_sizes[1]
        rails = [[[-RAIL_M, y, 0.0], [RAIL_M, y, 0.0]] for y in (-half_width, half_width)]
        metres = np.arange(-RAIL_M, RAIL_M + 0.5, 1.0)
        ticks = [[[x, -half_width - (0.4 if x % LABEL_EVERY_M == 0 else 0.2), 0.0],
                  [x, -half_width, 0.0]] for x in metres]
        rec.log(f"{world}/rail", rr.LineStrips3D(rails + ticks, colors=[RAIL_COLOR], radii=[0.02]),
                static=True)
        marks = np.arange(-RAIL_M, RAIL_M + 0.5, LABEL_EVERY_M)
        rec.log(f"{world}/rail/marks", rr.Points3D(
            np.column_stack([marks, np.full(marks.size, -half_width - 0.7), np.zeros(marks.size)]),
            radii=[0.04], colors=[RAIL_COLOR],
            labels=[f"{x:+.0f} m" if x else "0 m" for x in marks], show_labels=True), static=True)
        object.__setattr__(self, "_cart_height", 2.0 * geom.cart_half_sizes[2])

    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        import rerun as rr

        theta = np.asarray(x[:, 0], dtype=np.float64) * self.theta_sign
        cart_pos = np.asarray(extras.get("cart_pos", np.zeros_like(theta)), dtype=np.float64)
        height = self.__dict__.get("_cart_height", CART_SIZE[2])
        poses = cartpole_poses(cart_pos, theta, self.l, height)
        rec.send_columns(f"{world}/cart", indexes=[times],
                         columns=rr.Transform3D.columns(translation=poses.cart_translation))
        rec.send_columns(f"{world}/cart/readout", indexes=[times],
                         columns=rr.Points3D.columns(labels=readout_labels(cart_pos)))
        rec.send_columns(f"{world}/pole", indexes=[times],
                         columns=rr.Transform3D.columns(translation=poses.pole_translation,
                                                        quaternion=poses.pole_quaternion))

    def view(self, origin: str, suffix: str = "") -> Any:
        """The cart-pole seen from the side, the camera following the cart (the drift
        shows as the rail's metre marks passing by and in the readout)."""
        import rerun.blueprint as rrb

        l = self.l
        return rrb.Spatial3DView(
            origin=origin,
            # side by side (the cross-check) a view is half as wide: the short title
            name=f"cart-pole{suffix}" if suffix else "cart-pole (rail marks every 10 m, readout: cart position)",
            line_grid=rrb.LineGrid3D(visible=False),
            eye_controls=rrb.EyeControls3D(
                position=[0.0, -(3.0 * l + 8.0), l + 0.5], look_target=[0.0, 0.0, l - 0.5],
                eye_up=[0.0, 0.0, 1.0], tracking_entity=f"{origin}/cart"))


#: the cross-check's open-loop chirp: amplitude per kg of total mass
CHIRP_N_PER_KG = 100.0 / 11.0


class CartPoleDomain(Domain):
    """The cart-pole (C1)-(C2): an analytic ODE and a MuJoCo MJCF of one machine."""

    name = "cartpole"
    kinds = {"cartpole_ode": Backend(CartPoleConfig, _build_ode),
             "cartpole_mujoco": Backend(MujocoCartPoleConfig, _build_mujoco, mujoco=True)}
    labels = LABELS
    task = TaskDefaults(view=("hinge", "hinge_dot"), fall_angle=math.pi / 2, pole="hinge")
    default_model = MujocoCartPoleConfig.model
    rail_joint = "slider"

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, MujocoCartPoleConfig) else self.default_model

    def params_of_scenario(self, scenario: "Scenario") -> CartPoleParams:
        """The cart-pole a model-based controller assumes: the machine the plant is.

        For ``cartpole_ode`` the scenario's parameters; for ``cartpole_mujoco`` read back
        from the compiled model (masses, COM distance, pole inertia, damping, gear and the
        hinge axis' sign), so a baseline on a third-party MJCF assumes the machine MuJoCo
        actually simulates.  Friction is left out: a nominal model knows the rigid body,
        not what a rig adds to it.
        """
        params = self.build(scenario).params  # type: ignore[attr-defined]
        return replace(params, cart_damping=0.0, hinge_damping=0.0, cart_friction=0.0,
                       hinge_friction=0.0)

    def plant_model(self, scenario: "Scenario") -> PlantModel:
        # sliding mode's k = 0.5 rad/s^2: the disturbance is 0.05 / 41 ~ 1.2e-3 and the
        # linearisation's error ~ 2.6 theta^3 / 6 is smaller still; 0.5 gives a fast
        # reaching phase from theta(0) = pi/30
        return PlantModel(scenario.plant.kind, 2, accel_fn(self.params_of_scenario(scenario)),
                          affine_in_u=True, x_op=(0.0, 0.0), switching_gain=0.5)

    def drawing(self, plant: Plant, scenario: "Scenario") -> Drawing | None:
        params: CartPoleParams = plant.params  # type: ignore[attr-defined]
        mjcf = str(self.model_path(scenario)) if self.kinds[scenario.plant.kind].mujoco else ""
        return CartPoleDrawing(M=params.M, m=params.m, l=params.l, g=params.g, mjcf=mjcf,
                               theta_sign=params.theta_sign)

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        return "slide" in joint_types

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        hinge = plant.state_names[1]  # the MJCF's own name of the pole's hinge
        return (hinge, f"{hinge}_dot")

    def chirp_amplitude(self, plant: Plant) -> float:
        """100 N on the paper's 11 kg machine, scaled with the total mass (per unit gear)."""
        p: CartPoleParams = plant.params  # type: ignore[attr-defined]
        return CHIRP_N_PER_KG * (p.M + p.m) / abs(p.gear)

    def ode_of(self, plant: Plant) -> Plant:
        """The ODE of the MuJoCo ``plant``'s machine, with its joints' names and ranges."""
        ranges = {j.name: j.range for j in plant.joints if j.range is not None}
        return cartpole_ode_plant(plant.params, plant.slide_joint,  # type: ignore[attr-defined]
                                  plant.hinge_joint, ranges)  # type: ignore[attr-defined]


#: the cart-pole domain
DOMAIN = CartPoleDomain()
