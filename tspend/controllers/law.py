"""Laws written once, over an array namespace, and built for numba and for JAX from that text.

A *law* is a plain function whose array operations all go through the module-level name
``xp`` (:mod:`tspend.controllers.xp`) and its scalar functions through ``math``: it reads its numbers from NamedTuples of arrays
(the kind's design), writes arrays only through ``xp.put``/``xp.add`` and uses what they
return, chooses by data only with ``xp.where``, and loops over ranges that are sizes of
its design.  :func:`array_law` compiles it with numba for the CPU loops (``xp`` there writes
in place and allocates nothing); :func:`jax_form` builds the JAX form from the same code
object, with ``xp`` bound to :func:`jax_space` (``.at[].set``, ``jnp.where``), ``math``
to :func:`jax_math` and every law it calls bound to that law's JAX form.  So a law has one text: nothing can change in
one backend only (tests/test_law_backends.py names, for each kind, the function both
call).  This is ``FullModel.accel_factory(sin, cos, tanh)``'s pattern, with the
namespace a module global instead of an argument, so numba caches the compiled law on
disk as before.

Under JAX the design's numbers are constants of the trace (:func:`jax_design`): its
integer and boolean arrays (indices, sizes, flags) stay numpy, so loop bounds and
branches on settings are Python values there, as numba compiles them; its float arrays
become JAX arrays, which a traced index may read.
"""

from __future__ import annotations

import math
import types
from typing import Any, Callable

import numpy as np
from numba import njit

from tspend.runtime.jit import JIT

__all__ = ["array_law", "is_law", "jax_design", "jax_form", "jax_math", "jax_space", "mark_law"]

#: the Python functions written as laws (their numba builds' ``py_func``)
_LAWS: set[Callable] = set()
#: JAX forms already built, by Python function
_JAX_FORMS: dict[Callable, Callable] = {}


def array_law(fn: Callable) -> Any:
    """``fn`` compiled for the CPU loops (``njit`` with the package's options) and marked
    as a law, so :func:`jax_form` can rebuild it (and what calls it) for JAX."""
    _LAWS.add(fn)
    return njit(**JIT)(fn)


def is_law(fn: Any) -> bool:
    """Whether ``fn`` (a numba build or its Python function) is a law."""
    try:
        return getattr(fn, "py_func", fn) in _LAWS
    except TypeError:  # unhashable: not a function
        return False


def mark_law(fn: Callable) -> Callable:
    """Mark an arithmetic function already compiled elsewhere (``register_jitable``,
    its scalar functions ``math``'s) as a law, so laws that call it have a JAX form."""
    _LAWS.add(getattr(fn, "py_func", fn))
    return fn


def jax_space() -> types.SimpleNamespace:
    """The namespace ``xp`` of a law's JAX form: the names of
    :mod:`tspend.controllers.xp`, over ``jax.numpy``, writes returning new arrays."""
    import jax.numpy as jnp

    return types.SimpleNamespace(
        put=lambda a, index, value: a.at[index].set(value),
        add=lambda a, index, value: a.at[index].add(value),
        where=jnp.where)


def jax_math() -> types.SimpleNamespace:
    """What a law's JAX form finds under the name ``math``: ``jax.numpy``'s functions."""
    import jax.numpy as jnp

    return types.SimpleNamespace(
        sqrt=jnp.sqrt, ceil=jnp.ceil, floor=jnp.floor, exp=jnp.exp, sin=jnp.sin,
        cos=jnp.cos, tanh=jnp.tanh, fabs=jnp.abs, isnan=jnp.isnan, isfinite=jnp.isfinite,
        pi=math.pi, inf=math.inf, nan=math.nan)


def jax_form(fn: Any) -> Callable:
    """The JAX form of the law ``fn``: its own code object, with ``xp`` and ``math`` the
    JAX namespaces and every law named in its globals replaced by that law's JAX form."""
    py = getattr(fn, "py_func", fn)
    if py not in _LAWS:
        raise TypeError(f"{py.__qualname__} is not a law (tspend.controllers.law.array_law)")
    if py in _JAX_FORMS:
        return _JAX_FORMS[py]
    scope = dict(py.__globals__)
    scope["xp"], scope["math"] = jax_space(), jax_math()
    built = types.FunctionType(py.__code__, scope, py.__name__, py.__defaults__,
                               py.__closure__)
    _JAX_FORMS[py] = built
    for name in py.__code__.co_names:
        callee = scope.get(name)
        if callee is not None and name not in ("xp", "math") and is_law(callee):
            scope[name] = jax_form(callee)
    return built


def jax_design(design: Any, every_array: bool = False) -> Any:
    """``design`` (NamedTuples of numbers and numpy arrays) with every float array a JAX
    array, a constant of the trace that calls the law (integer and boolean arrays stay
    numpy: static indices and flags); ``every_array``: every array (a scratch the law
    writes, integer spans included)."""
    import jax
    import jax.numpy as jnp

    def convert(leaf):
        if isinstance(leaf, np.ndarray) and (every_array or
                                             np.issubdtype(leaf.dtype, np.floating)):
            return jnp.asarray(leaf)
        return leaf

    return jax.tree_util.tree_map(convert, design)
