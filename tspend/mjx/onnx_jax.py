"""An ONNX policy's graph evaluated in JAX: the ``policy`` kind on the mjx backend.

The graph's nodes are run in order by their JAX equivalents, with the weights (the
graph's initializers) as a pytree of arrays, so the function jit-compiles and vmaps.
The operations of tspend's policies (benchmarks/train_policy.py, examples/train_mjx_ppo.py)
and of the usual MLP exports are covered; a graph using another is refused in one line
naming it.  Needs the ``onnx`` package (the ``mjx`` extra) to read the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["OPS", "onnx_function"]


def _attrs(node: Any) -> dict:
    from onnx import helper

    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def _gemm(x, a, b, c=None, alpha=1.0, beta=1.0, transA=0, transB=0):
    import jax.numpy as jnp

    x = x.T if transA else x
    a = a.T if transB else a
    y = alpha * jnp.matmul(x, a)
    return y if c is None else y + beta * c


def _clip(x, lo=None, hi=None):
    import jax.numpy as jnp

    if lo is not None:
        x = jnp.maximum(x, lo)
    if hi is not None:
        x = jnp.minimum(x, hi)
    return x


def _ops() -> dict[str, Callable]:
    import jax
    import jax.numpy as jnp

    return {
        "Add": lambda a, b, **_: a + b, "Sub": lambda a, b, **_: a - b,
        "Mul": lambda a, b, **_: a * b, "Div": lambda a, b, **_: a / b,
        "Neg": lambda a, **_: -a, "Identity": lambda a, **_: a,
        "MatMul": lambda a, b, **_: jnp.matmul(a, b),
        "Gemm": lambda a, b, c=None, **k: _gemm(a, b, c, **k),
        "Tanh": lambda a, **_: jnp.tanh(a), "Relu": lambda a, **_: jnp.maximum(a, 0),
        "Sigmoid": lambda a, **_: jax.nn.sigmoid(a), "Exp": lambda a, **_: jnp.exp(a),
        "Clip": lambda a, lo=None, hi=None, **_: _clip(a, lo, hi),
        "Gather": lambda a, i, axis=0, **_: jnp.take(a, i, axis=axis),
        "Concat": lambda *xs, axis=0, **_: jnp.concatenate(xs, axis=axis),
        "Reshape": lambda a, s, **_: a.reshape(tuple(int(v) for v in np.asarray(s))),
        "Squeeze": lambda a, axes=None, **_: jnp.squeeze(a, axis=None if axes is None
                                                         else tuple(np.asarray(axes).tolist())),
        "Cast": lambda a, to=1, **_: a.astype(_dtype_of(to)),
    }


#: the ONNX operations evaluated
OPS = ("Add", "Sub", "Mul", "Div", "Neg", "Identity", "MatMul", "Gemm", "Tanh", "Relu",
       "Sigmoid", "Exp", "Clip", "Gather", "Concat", "Reshape", "Squeeze", "Cast")


def _dtype_of(elem_type: int) -> Any:
    return {1: np.float32, 11: np.float64, 7: np.int64, 6: np.int32}.get(int(elem_type), np.float32)


def onnx_function(path: str | Path) -> tuple[Callable, dict, Any]:
    """``(fn, params, dtype)``: ``fn(params, obs)`` is the graph's first output for a batch
    of observations ``obs`` (rows); ``dtype`` the graph input's type."""
    try:
        import onnx
        from onnx import numpy_helper
    except ImportError:
        raise ScenarioError("the policy kind on the mjx backend reads the .onnx graph with "
                            "the onnx package: pip install 'tspend[mjx]'") from None
    model = onnx.load(str(path))
    graph = model.graph
    ops = _ops()
    for node in graph.node:
        if node.op_type not in ops:
            raise ScenarioError(f"{path}: ONNX operation {node.op_type} has no JAX form here "
                                f"(evaluated: {', '.join(OPS)}); run the policy on the CPU "
                                f"backend")
    params = {init.name: np.asarray(numpy_helper.to_array(init)) for init in graph.initializer}
    # ints (indices, shapes) stay numpy so they are static under jit
    static = {k: v for k, v in params.items() if v.dtype.kind in "iu"}
    weights = {k: v for k, v in params.items() if k not in static}
    inputs = [i for i in graph.input if i.name not in params]
    if len(inputs) != 1:
        raise ScenarioError(f"{path}: the graph must take one input (the observation)")
    name = inputs[0].name
    dtype = _dtype_of(inputs[0].type.tensor_type.elem_type)
    nodes = [(n.op_type, list(n.input), list(n.output), _attrs(n)) for n in graph.node]
    out_name = graph.output[0].name

    def fn(p: dict, obs: Any) -> Any:
        values: dict[str, Any] = {name: obs, **static, **p}
        for op, ins, outs, attrs in nodes:
            args = [values[i] if i else None for i in ins]
            values[outs[0]] = ops[op](*args, **attrs)
        return values[out_name]

    import jax.numpy as jnp

    return fn, {k: jnp.asarray(v) for k, v in weights.items()}, dtype
