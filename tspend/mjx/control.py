"""The controller kinds with a JAX form, designed on the CPU as the CPU backend designs them.

:func:`jax_law` builds the kind's CPU controller (``tspend.loop.simulation.prepare``:
the LQR gain from the nominal machine's linearisation, the PD gains, the ONNX file) and
returns its law as a pure JAX function ``u = law(params, full, ref)`` of the full state
and the reference row ``r .. r^(n)``, with the numbers in ``params`` (a pytree of
arrays).  The laws are the CPU kinds' equations, read from the same numbers the compiled
CPU laws read (``PDLaw``, ``ViewLQRLaw``, ``FullLQRLaw``: tspend/controllers/pd.py and
lqr.py state them): pd, u = (r^(n) - k^T e) / b0; lqr (view design), u = u* + (r^(n) -
a^T (r - x*)) / b - K e; lqr (full-state design), u = u_r - K (s - s_r) with angle errors
wrapped.  ``policy``: the ONNX graph's own operations evaluated in JAX
(:mod:`tspend.mjx.onnx_jax`) on the observation the CPU kind builds, [full state, r ..
r^(n)], in the graph's input type.  Any other kind is refused in one line.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["KINDS", "jax_law"]

#: the kinds that have a JAX form
KINDS = ("pd", "lqr", "policy")


def _refuse(kind: str) -> ScenarioError:
    return ScenarioError(f"controller kind {kind!r} has no JAX form: the mjx backend runs "
                         f"{', '.join(KINDS)}; run {kind} on the CPU backend")


def jax_law(scenario: Any, controller: Any, view_index: np.ndarray,
            wraps_full: np.ndarray) -> tuple[Callable, Any, float]:
    """``(law, params, sample_period_s)`` of the CPU ``controller`` (already built on the
    nominal scenario); ``view_index``: the task's view in the full state; ``wraps_full``:
    which full-state entries are revolute angles."""
    import jax.numpy as jnp

    from tspend.controllers.lqr import FullLQRLaw, ViewLQRLaw
    from tspend.controllers.pd import PDLaw

    kind = controller.kind
    if kind not in KINDS:
        raise _refuse(kind)
    view = jnp.asarray(view_index)
    period = float(getattr(controller, "sample_period", 0.0) or 0.0)
    if kind == "policy":
        from tspend.controllers.policy import PolicySettings, find_policy
        from tspend.controllers.settings import settings_for
        from tspend.mjx.onnx_jax import onnx_function

        path = find_policy(settings_for(scenario, PolicySettings).path, scenario)
        fn, params, dtype = onnx_function(path)

        def policy(p, full, ref):
            row = jnp.concatenate((full, ref)).astype(dtype)[None, :]
            return fn(p, row).reshape(-1)[0].astype(full.dtype)

        return policy, params, period
    law = getattr(controller, "law", None)
    if isinstance(law, PDLaw):
        params = {"k": jnp.asarray(law.k), "b0": jnp.asarray(law.b0)}

        def pd(p, full, ref):
            n = p["k"].size
            ke = jnp.dot(p["k"], full[view] - ref[:n])
            return ref[n] / p["b0"] + (-ke / p["b0"])

        return pd, params, period
    if isinstance(law, ViewLQRLaw):
        params = {"K": jnp.asarray(law.K), "a": jnp.asarray(law.a), "b": jnp.asarray(law.b),
                  "x_op": jnp.asarray(law.x_op), "u_op": jnp.asarray(law.u_op)}

        def view_lqr(p, full, ref):
            n = p["K"].size
            ar = jnp.dot(p["a"], ref[:n] - p["x_op"])
            u_fb = -jnp.dot(p["K"], full[view] - ref[:n])
            return (p["u_op"] + (ref[n] - ar) / p["b"]) + u_fb

        return view_lqr, params, period
    if isinstance(law, FullLQRLaw):
        N = law.K.size
        pole, act, dof = int(law.pole), int(law.actuated), int(law.dof)
        # s_r = M ref[:2]: the pole's angle and rate follow r, r'; the actuated joint kappa r
        M = np.zeros((N, 2))
        M[pole, 0] = M[dof + pole, 1] = 1.0
        M[act, 0] = M[dof + act, 1] = law.kappa
        params = {"K": jnp.asarray(law.K), "a_pole": jnp.asarray(law.a_pole),
                  "b_pole": jnp.asarray(law.b_pole), "M": jnp.asarray(M),
                  "wraps": jnp.asarray(np.asarray(law.wraps, dtype=bool))}

        def full_lqr(p, full, ref):
            s_r = p["M"] @ ref[:2]
            u_ff = (ref[2] - jnp.dot(p["a_pole"], s_r)) / p["b_pole"]
            d = full - s_r
            # tspend.plants.domain.wrap_angle: to (-pi, pi]
            wrapped = d - 2.0 * jnp.pi * jnp.ceil((d - jnp.pi) / (2.0 * jnp.pi))
            e = jnp.where(p["wraps"] & (jnp.abs(d) > jnp.pi), wrapped, d)
            return u_ff + (-jnp.dot(p["K"], e))

        return full_lqr, params, period
    raise _refuse(f"{kind} ({type(controller).__name__})")
