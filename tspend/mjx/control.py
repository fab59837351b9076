"""A controller kind in JAX: its law's JAX form, designed on the CPU as the CPU backend
designs it.

Every arithmetic kind's law is written once (:mod:`tspend.runtime.law`) and offered
by the CPU controller's :meth:`~tspend.controllers.base.Controller.compiled` (the
``law`` of :class:`~tspend.controllers.base.CompiledController`): its numbers are the
controller's design (made on the nominal machine: the LQR gain, the PD gains, the rule
bases), its carry the controller's adapted state.  :func:`jax_law` returns that law's
JAX form as a pure step ``u, carry = law(carry, t, full, ref, dt)`` of the full state
and the reference row ``r .. r^(n)``; a kind without such a law (the solver kinds: mpc,
the QP filters) is refused in one line.  ``policy``: the ONNX graph's own operations
evaluated in JAX (:mod:`tspend.mjx.onnx_jax`) on the observation the CPU kind builds,
[full state, r .. r^(n)], in the graph's input type; it carries nothing.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["jax_law", "seeded_carries"]


def _refuse(kind: str) -> ScenarioError:
    return ScenarioError(f"controller kind {kind!r} has no JAX form (its law calls a solver "
                         f"or is not written over an array namespace); run {kind} on the "
                         f"CPU backend")


def jax_law(scenario: Any, controller: Any, view_index: np.ndarray,
            dtype: Any = None) -> tuple[Callable, Any, float]:
    """``(law, carry, sample_period_s)`` of the CPU ``controller`` (already built on the
    nominal scenario and reset): ``u, carry = law(carry, t, full, ref, dt)``, pure, for
    ``jax.jit``/``jax.vmap``; ``carry`` its start (the controller's state now, in
    ``dtype``'s floats); ``view_index``: the task's view in the full state."""
    from tspend.runtime.law import jax_step

    period = float(getattr(controller, "sample_period", 0.0) or 0.0)
    if controller.kind == "policy":
        return _policy_law(scenario, period)
    compiled = controller.compiled()
    if compiled is None or compiled.law is None:
        raise _refuse(controller.kind)
    step = jax_step(compiled.law, compiled.settings, compiled.scratch,
                    np.asarray(controller.diag).size)
    view = np.asarray(view_index)

    def law(carry, t, full, ref, dt):
        return step(carry, t, full, full[view], ref, dt)

    return law, _carry(compiled.state, dtype), period


def _carry(state: Any, dtype: Any) -> Any:
    """A copy of a compiled controller's ``state`` as JAX arrays, floats in ``dtype``."""
    import jax
    import jax.numpy as jnp

    def start(leaf):
        a = np.array(leaf)
        if dtype is not None and np.issubdtype(a.dtype, np.floating):
            a = a.astype(dtype)
        return jnp.asarray(a)

    return jax.tree_util.tree_map(start, state)


def seeded_carries(controller: Any, seeds: Any, dtype: Any = None) -> Any:
    """The law's carry at the start of each seed's run, stacked on a leading env axis: the
    controller reset as the CPU run resets it (``np.random.default_rng(seed)``,
    :func:`tspend.loop.simulation.build_controller`), so an adaptive kind starts each
    env from the parameters its CPU run draws; the controller is left reset at the last."""
    import jax
    import jax.numpy as jnp

    if controller.kind == "policy":
        return None
    carries = []
    for seed in seeds:
        controller.reset(np.random.default_rng(int(seed)))
        compiled = controller.compiled()
        if compiled is None or compiled.law is None:
            raise _refuse(controller.kind)
        carries.append(_carry(compiled.state, dtype))
    return jax.tree_util.tree_map(lambda *leaves: jnp.stack(leaves), *carries)


def _policy_law(scenario: Any, period: float) -> tuple[Callable, Any, float]:
    import jax.numpy as jnp

    from tspend.controllers.policy import PolicySettings, find_policy
    from tspend.controllers.settings import settings_for
    from tspend.mjx.onnx_jax import onnx_function

    path = find_policy(settings_for(scenario, PolicySettings).path, scenario)
    fn, params, dtype = onnx_function(path)

    def policy(carry, t, full, ref, dt):
        # the graph's weights are constants of the trace: one copy, not one per env
        row = jnp.concatenate((full, ref)).astype(dtype)[None, :]
        return fn(params, row).reshape(-1)[0].astype(full.dtype), carry

    return policy, None, period
