"""Laws written once, over an array namespace, and built for numba and for JAX from that text.

A *law* is a plain function whose array operations all go through the module-level name
``xp`` (:mod:`tspend.runtime.xp`) and its scalar functions through ``math``: it reads its numbers from NamedTuples of arrays
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

__all__ = ["Cells", "Slots", "array_law", "as_arrays", "as_cells", "is_law", "jax_design",
           "jax_form", "jax_math", "jax_space", "jax_step", "mark_law", "with_jax_form"]

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


def with_jax_form(jax_fn: Callable) -> Callable[[Callable], Callable]:
    """Mark ``fn`` as a law whose JAX form is ``jax_fn``: for the few functions where the
    backends must differ in *how* they reach one text, not in what it computes (a
    generated model's numba build is called by its C address, its JAX build is the
    same generated source evaluated over ``jax.numpy``: :mod:`tspend.plants.articulated.derive`)."""
    def mark(fn: Callable) -> Callable:
        py = getattr(fn, "py_func", fn)
        _LAWS.add(py)
        _JAX_FORMS[py] = jax_fn
        return fn

    return mark


def _write(a: Any, index: Any, value: Any, accumulate: bool) -> Any:
    if isinstance(a, Cells):
        return a.write(index, value, accumulate)
    return a.at[index].add(value) if accumulate else a.at[index].set(value)


def jax_space() -> types.SimpleNamespace:
    """The namespace ``xp`` of a law's JAX form: the names of
    :mod:`tspend.runtime.xp`, over ``jax.numpy``, writes returning new arrays."""
    import jax.numpy as jnp

    return types.SimpleNamespace(
        put=lambda a, index, value: _write(a, index, value, False),
        add=lambda a, index, value: _write(a, index, value, True),
        where=jnp.where, rounded_index=lambda v: jnp.round(v).astype(jnp.int64))


def _static(i: Any) -> bool:
    return isinstance(i, (int, np.integer, slice))


class Cells:
    """A JAX array as a law's JAX form reads and writes it: by its scalar entries.

    A law is written entry by entry (numba compiles loops); traced as is, every read
    ``a[i, k]`` and every write ``xp.put(a, (i, k), v)`` of a JAX array would be an XLA
    slice or scatter, tens of thousands for the paper's controller, and XLA's compile
    time grows with them.  A :class:`Cells` keeps the entries written at static
    indices in a dict and those read in another, so static reads and writes cost no
    operation at all; the array is assembled (one scatter) only where an index is
    traced or the law returns it.  Values, never views: every write returns a new one.
    """

    def __init__(self, base: Any, written: dict | None = None) -> None:
        self.base = base                      # the array before the writes, flat
        self.shape = tuple(base.shape)
        self.written = written or {}          # flat index -> value written
        self._read: dict[int, Any] = {}
        self._array: Any = None

    @classmethod
    def of(cls, a: Any) -> "Cells":
        import jax.numpy as jnp

        a = jnp.asarray(a)
        cells = cls(a.reshape(-1))
        cells.shape = tuple(a.shape)
        if not cells.written:
            cells._array = a
        return cells

    size = property(lambda self: int(np.prod(self.shape, dtype=np.int64)))
    ndim = property(lambda self: len(self.shape))
    dtype = property(lambda self: self.base.dtype)

    def cell(self, k: int) -> Any:
        if k in self.written:
            return self.written[k]
        if k not in self._read:
            self._read[k] = self.base[k]
        return self._read[k]

    def array(self) -> Any:
        """The whole array (one scatter of the written entries into the base)."""
        import jax.numpy as jnp

        if self._array is None:
            flat = self.base
            if self.written:
                keys = np.fromiter(self.written, dtype=np.int64)
                flat = flat.at[keys].set(jnp.stack([jnp.asarray(self.written[int(k)],
                                                                dtype=flat.dtype)
                                                    for k in keys]))
            self._array = flat.reshape(self.shape)
        return self._array

    __jax_array__ = array

    def _positions(self, index: tuple) -> np.ndarray:
        return np.arange(self.size).reshape(self.shape)[index]

    def __getitem__(self, index: Any) -> Any:
        index = index if isinstance(index, tuple) else (index,)
        if not all(_static(i) for i in index):
            return self.array()[index]
        at = self._positions(index)
        if at.ndim == 0:
            return self.cell(int(at))
        sub = Cells(self.base[at.reshape(-1)],
                    {j: self.written[int(k)] for j, k in enumerate(at.reshape(-1))
                     if int(k) in self.written})
        sub.shape = tuple(at.shape)
        return sub

    def write(self, index: Any, value: Any, accumulate: bool) -> "Cells":
        index = index if isinstance(index, tuple) else (index,)
        if all(isinstance(i, (int, np.integer)) for i in index) and len(index) == self.ndim:
            k = int(self._positions(index))
            new = Cells(self.base, dict(self.written))
            new.shape = self.shape
            new._read = self._read
            new.written[k] = self.cell(k) + value if accumulate else value
            return new
        a = self.array()
        return Cells.of(a.at[index].add(value) if accumulate else a.at[index].set(value))


class Slots(Cells):
    """A :class:`Cells` that generated straight-line code writes in place (``a[k] = v``,
    static ``k``), as its numba build writes a numpy array: the JAX form of a generated
    model (:func:`tspend.plants.articulated.derive.jax_functions`) runs on these."""

    @classmethod
    def of(cls, a: Any) -> "Slots":
        cells = a if isinstance(a, Cells) else Cells.of(a)
        slots = cls(cells.base, dict(cells.written))
        slots.shape = cells.shape
        return slots

    def __setitem__(self, index: Any, value: Any) -> None:
        index = index if isinstance(index, tuple) else (index,)
        self.written[int(self._positions(index))] = value
        self._array = None

    def frozen(self) -> Cells:
        """What was written, as a value (a :class:`Cells` no one writes again)."""
        cells = Cells(self.base, dict(self.written))
        cells.shape = self.shape
        return cells


def as_cells(tree: Any) -> Any:
    """Every JAX array of ``tree`` as :class:`Cells` (numpy arrays stay: static)."""
    import jax

    return jax.tree_util.tree_map(
        lambda leaf: Cells.of(leaf) if isinstance(leaf, jax.Array) else leaf, tree)


def as_arrays(tree: Any) -> Any:
    """Every :class:`Cells` of ``tree`` as its JAX array."""
    import jax

    return jax.tree_util.tree_map(lambda leaf: leaf.array() if isinstance(leaf, Cells)
                                  else leaf, tree, is_leaf=lambda x: isinstance(x, Cells))


def jax_step(fn: Any, settings: Any, scratch: Any, diag_size: int) -> Callable:
    """The law ``fn`` (a kind's :attr:`~tspend.controllers.base.CompiledController.law`)
    in JAX over the design ``settings`` and the work arrays ``scratch``: a pure
    ``u, state = step(state, t, full, x, ref, dt)``."""
    import jax.numpy as jnp

    form = jax_form(fn)
    design = jax_design(settings)
    work = jax_design(scratch, every_array=True)
    diag = jnp.zeros(diag_size)

    def step(state, t, full, x, ref, dt):
        u, state = form(as_cells(design), as_cells(state), as_cells(work), t,
                        Cells.of(full), Cells.of(x), Cells.of(ref), dt, Cells.of(diag))
        return jnp.asarray(u, dtype=jnp.asarray(full).dtype), as_arrays(state)

    return step


def jax_math() -> types.SimpleNamespace:
    """What a law's JAX form finds under the name ``math``: ``jax.numpy``'s functions."""
    import jax.numpy as jnp

    return types.SimpleNamespace(
        sqrt=jnp.sqrt, ceil=jnp.ceil, floor=jnp.floor, exp=jnp.exp, sin=jnp.sin,
        cos=jnp.cos, tan=jnp.tan, tanh=jnp.tanh, log=jnp.log, atan2=jnp.arctan2, fabs=jnp.abs, copysign=jnp.copysign, isnan=jnp.isnan, isfinite=jnp.isfinite,
        pi=math.pi, inf=math.inf, nan=math.nan)


def jax_form(fn: Any) -> Callable:
    """The JAX form of the law ``fn``: its own code object, with ``xp`` and ``math`` the
    JAX namespaces and every law named in its globals replaced by that law's JAX form."""
    py = getattr(fn, "py_func", fn)
    if py not in _LAWS:
        raise TypeError(f"{py.__qualname__} is not a law (tspend.runtime.law.array_law)")
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
