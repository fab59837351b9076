"""Each arithmetic kind's law is one text, built for numba and for JAX
(tspend/runtime/law.py); here both builds are evaluated on the same 1,000 drawn
states, references and adaptive states and must agree within 1e-12 relative (u; an
adaptive state's arrays relative to their largest entry).

The law both backends call is the ``law`` of the kind's
:class:`~tspend.controllers.base.CompiledController`, named in :data:`CASES`: the CPU
loop calls its numba build, the mjx backend its JAX form (:func:`tspend.runtime.law.jax_form`,
the same code object with another ``xp``), so a law changed in one backend only cannot
exist; the test fails if the kind's law is another function or has no JAX form.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

jax = pytest.importorskip("jax")

from tspend.runtime.law import jax_form, jax_step  # noqa: E402
from tspend.loop.simulation import prepare  # noqa: E402
from tspend.scenario import load_scenario, override  # noqa: E402

#: (scenario, kind, overrides, the law both backends call)
CASES = [
    ("pendulum_mujoco_randomized", "pd", {}, "tspend.controllers.pd.pd_law"),
    ("ex3_pendulum_ode", "lqr", {"controllers.lqr.design": "view"},
     "tspend.controllers.lqr.view_lqr_law"),
    ("double_cartpole_mujoco", "lqr", {}, "tspend.controllers.lqr.full_lqr_control"),
    ("pendulum_mujoco_randomized", "sliding_mode", {}, "tspend.controllers.sliding_mode.sliding_law"),
    ("ex3_pendulum_ode", "wang_indirect", {},
     "tspend.controllers.wang_indirect.wang_law"),
    ("pendulum_mujoco_randomized", "second_type", {},
     "tspend.controllers.paper.controller.controller_law"),
    ("pendulum_mujoco_randomized", "first_type", {},
     "tspend.controllers.paper.controller.controller_law"),
    # the MJCF-derived model's generated source, evaluated over jax.numpy
    ("pendulum_mujoco_randomized", "feedback_linearization", {},
     "tspend.controllers.feedback_linearization.oracle_law"),
    ("swingup_mujoco", "swingup", {}, "tspend.controllers.swingup.swingup_law"),
    ("furuta_swingup", "swingup", {}, "tspend.controllers.swingup.swingup_law"),
]
DRAWS = 1000
RTOL = 1e-12


def _built(scenario: str, kind: str, overrides: dict):
    scn = load_scenario(scenario)
    if overrides:
        scn = override(scn, **overrides)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prepared = prepare(scn, controller=kind)
    return prepared


def _draws(rng, c, full_size: int):
    """A drawn full state, reference row and adaptive state around the controller's."""
    n = c.order
    full = rng.uniform(-1.0, 1.0, full_size)
    ref = rng.uniform(-1.0, 1.0, n + 1)
    compiled = c.compiled()
    state = jax.tree_util.tree_map(
        lambda a: a * rng.uniform(0.5, 1.5, np.shape(a)) if np.issubdtype(np.asarray(a).dtype,
                                                                           np.floating) else a,
        jax.tree_util.tree_map(np.array, compiled.state))
    return full, ref, state


@pytest.mark.parametrize("scenario, kind, overrides, name", CASES)
def test_cpu_and_jax_laws_agree_on_drawn_states(scenario, kind, overrides, name):
    jax.config.update("jax_enable_x64", True)
    _check_on_draws(_built(scenario, kind, overrides), kind, name)


def test_tvlqr_law_agrees_on_drawn_states_following_and_after_a_plan(tmp_path):
    """tvlqr's law over a given plan (here 0.2 s of made-up rows: the law is table lookup
    and arithmetic whatever the rows), its clock started at 0 so the 1,000 draws' times
    fall within the plan and after it (the LQR)."""
    from tspend.controllers.trajectory import Plan, write_plan

    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(29)
    t = np.arange(201) * 1e-3
    plan = Plan(t, rng.uniform(-1.0, 1.0, (t.size, 4)), rng.uniform(-5.0, 5.0, t.size),
                ("slider", "hinge", "slider_dot", "hinge_dot"), ("m", "rad", "m/s", "rad/s"),
                "force", "N", 1e-3, 0.02)
    write_plan(plan, tmp_path / "plan.parquet")
    prepared = _built("swingup_mujoco", "tvlqr",
                      {"controllers.tvlqr.plan": str(tmp_path / "plan.parquet")})
    prepared.controller.clock[:] = (0.0, 1.0)
    _check_on_draws(prepared, "tvlqr", "tspend.controllers.tvlqr.tvlqr_law")


def _check_on_draws(prepared, kind: str, name: str) -> None:
    c = prepared.controller
    compiled = c.compiled()
    assert f"{compiled.law.__module__}.{compiled.law.__name__}" == name
    # one text: the JAX form runs the very code object numba compiled
    assert jax_form(compiled.law).__code__ is compiled.law.py_func.__code__
    form = jax.jit(jax_step(compiled.law, compiled.settings, compiled.scratch, c.diag.size))
    view = np.asarray(prepared.task.view_index)
    full_size = len(prepared.task.names)
    rng = np.random.default_rng(52)
    dt = 1e-3
    for i in range(DRAWS):
        full, ref, state = _draws(rng, c, full_size)
        x = full[view]
        t = i * dt
        cpu_state = jax.tree_util.tree_map(np.array, state)
        u_cpu, after_cpu = compiled.law(compiled.settings, cpu_state, compiled.scratch, t, full,
                                        x, ref, dt, np.zeros(c.diag.size))
        u_jax, after_jax = form(state, t, full, x, ref, dt)
        np.testing.assert_allclose(float(u_jax), u_cpu, rtol=RTOL, atol=0.0,
                                   err_msg=f"{kind} u, draw {i}")
        for a, b in zip(jax.tree_util.tree_leaves(after_jax),
                        jax.tree_util.tree_leaves(after_cpu)):
            # relative to the array's largest entry: a control point that started at 0
            # holds only its increment, whose last bits XLA may round differently
            np.testing.assert_allclose(np.asarray(a), b, rtol=RTOL,
                                       atol=RTOL * float(np.max(np.abs(b), initial=0.0)),
                                       err_msg=f"{kind} state, draw {i}")


@pytest.mark.parametrize("scenario, kind", [
    ("pendulum_mujoco_randomized", "sliding_mode"), ("pendulum_mujoco_randomized", "second_type"),
    ("pendulum_mujoco_randomized", "first_type"),
    # the derived model's generated source in JAX: the oracle and the energy swing-up
    ("pendulum_mujoco_randomized", "feedback_linearization"), ("swingup_mujoco", "swingup")])
def test_mjx_sweep_of_an_adaptive_or_switching_kind_is_the_cpu_sweep(scenario, kind):
    """The mjx backend runs the kind's JAX law with its state as the scan's carry, each
    env's state drawn as its CPU run draws it: the rows agree (status equal; rmse,
    rmse_ss within 1e-9 relative in float64).  2 seeds, the first 2 s."""
    pytest.importorskip("mujoco.mjx")
    import tspend

    scn = override(load_scenario(scenario), **{"run.duration": 2.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu = tspend.sweep(scn, seeds="0:2", controllers=kind, jobs=1, record="none")
        mjx = tspend.sweep(scn, seeds="0:2", controllers=kind, jobs=1, record="none",
                           backend="mjx")
    assert list(mjx["status"]) == list(cpu["status"])
    for key in ("rmse", "rmse_ss"):
        np.testing.assert_allclose(mjx[key].to_numpy(float), cpu[key].to_numpy(float),
                                   rtol=1e-9, err_msg=key)


def test_the_derived_model_in_jax_is_the_generated_source_numba_compiled():
    """The MJCF-derived model's JAX form (what feedback_linearization's and swingup's
    laws reach through ``call_rhs``) runs the statements of the generated module numba
    compiled: its code comes from that module's file, and it gives the numba build's
    ``s'`` at drawn states, inputs and forces (the double cart-pole: 3 joints)."""
    import jax.numpy as jnp

    from tspend.loop.simulation import nominal_machine
    from tspend.plants.articulated.derive import jax_function_at
    from tspend.plants.articulated.domain import derived_rhs_of
    from tspend.plants.base import MachinePlant, read_as
    from tspend.runtime.law import Cells, Slots

    jax.config.update("jax_enable_x64", True)
    machine = read_as(nominal_machine(load_scenario("double_cartpole_mujoco")),
                      MachinePlant).machine
    built = jax_function_at(derived_rhs_of(machine, machine.view_joint).fn)
    assert built.__code__.co_filename == machine.module.__file__
    nv, nu = machine.nv, len(machine.tree.actuators)
    rng = np.random.default_rng(7)
    for _ in range(5):
        s, u, qfrc = rng.uniform(-1.0, 1.0, 2 * nv), rng.uniform(-1.0, 1.0, nu), rng.uniform(-1.0, 1.0, nv)
        want = np.zeros(2 * nv)
        machine.module.rhs(s, u, qfrc, machine.p, np.zeros(nv * nv), np.zeros(nv), want)
        got = Slots.of(jnp.zeros(2 * nv))
        built(Cells.of(s), Cells.of(u), Cells.of(qfrc), Cells.of(machine.p),
              Slots.of(jnp.zeros(nv * nv)), Slots.of(jnp.zeros(nv)), got)
        np.testing.assert_allclose(np.asarray(got.array()), want, rtol=1e-12, atol=1e-12)
