"""The array namespace ``xp`` of the compiled CPU loop: what a law (:mod:`tspend.runtime.law`)
names its array operations by, as numba compiles them.

A law writes an array only through :func:`put` and :func:`add` and uses the array they
return (``e = xp.put(e, j, v)``): here that writes in place and returns the same array,
so nothing is allocated (the compiled loop runs without numba's runtime, ``_nrt=False``);
JAX's namespace (:func:`tspend.runtime.law.jax_space`) returns a new array instead.
A choice that depends on data is :func:`where`, which both namespaces evaluate as a
select of two values already computed.  Scalar functions are ``math``'s, which the JAX
form replaces with ``jax.numpy``'s.
"""

from __future__ import annotations

from numba import njit

from tspend.runtime.jit import JIT

__all__ = ["add", "put", "rounded_index", "where"]


@njit(**JIT)
def put(a, index, value):
    """``a[index] = value``, in place; returns ``a``."""
    a[index] = value
    return a


@njit(**JIT)
def add(a, index, value):
    """``a[index] += value``, in place; returns ``a``."""
    a[index] += value
    return a


@njit(**JIT)
def where(condition, if_true, if_false):
    """``if_true`` where ``condition`` holds, else ``if_false`` (scalars)."""
    return if_true if condition else if_false


@njit(**JIT)
def rounded_index(v):
    """``v`` rounded to the nearest integer (halves to even), as an index."""
    return int(round(v))
