"""Rerun recorder: a :class:`~tspend.sinks.Sink` that streams a closed-loop run to Rerun.

What is logged (entity paths relative to the sink's ``prefix``):

- ``info/scenario``, ``info/run``: static markdown at start: the scenario's TOML, seed,
  package version, plant kind, order, dt, ...
- ``info/status``, ``info/metrics``: static markdown at :meth:`RerunSink.finish`
- ``events``: a ``TextLog`` at the last time when a run does not complete
- ``series/<group>``: multi-instance ``Scalars``, see :func:`series_specs`
- ``world/cart``, ``world/pole``: static ``Boxes3D`` / ``Capsules3D`` and a
  ``Transform3D`` per body at ~50 Hz (cart-poles only)
- ``fuzzy/model/in<j>``, ``fuzzy/compensator/in<j>``: membership curves
  (``LineStrips2D``, one strip per term) and the operating point (``Points2D``)
- ``fuzzy/firing``, ``fuzzy/compensator_firing``, ``fuzzy/q``: ``BarChart``;
  ``fuzzy/consequents``: ``Tensor`` (rule x k)

Everything time-dependent lives on the ``sim_time`` duration timeline and is sent in
columns, never row by row.  Rerun turns each entity's columns into a chunk, and a chunk
costs a fixed ~50 us to convert plus ~50 us of Python around ``send_columns``, whatever
its size.  So: series that share a plot share an entity (multi-instance ``Scalars``);
all entities of a block go out as one arrow record batch (``send_record_batch``, ~20-40 us
per chunk); 3D frames and inner snapshots (50 Hz) are batched ``DECIMATED_ROWS`` at a
time; membership curves are only re-sent when they change; ``TensorData`` columns are
built directly in arrow (the SDK converts each tensor in Python, ~0.4 ms apiece).

Rerun's 2D views draw y downwards (rerun-io/rerun#1387), so membership curves are
logged with ``y = -mu``: peaks point up on screen.

Where things are:

- :mod:`.sink`: :class:`RerunSink` (the sink protocol) and its snapshot buffer
- :mod:`.stream`: :func:`open_recording` / :func:`close_recording`, viewer spawn/connect
  and their fallbacks
- :mod:`.series`: which per-step series go to which entity (:func:`series_specs`)
- :mod:`.cartpole`: 3D cart-pole poses and geometry (from the MJCF geoms)
- :mod:`.blueprint`: the default viewer layout (:func:`build_blueprint`)
- :mod:`.documents`: the markdown documents (run, scenario, status, metrics)
- :mod:`.arrow`: arrow columns and record batches built directly
- :mod:`.readback`: reading series back from an ``.rrd`` (:func:`read_scalar_series`)
- :mod:`.common`: the timeline, entity paths and colours they share
"""

from __future__ import annotations

from .blueprint import build_blueprint
from .cartpole import (
    CART_SIZE,
    DEFAULT_POLE_HALF_LENGTH,
    POLE_RADIUS,
    CartPoleGeometry,
    CartPolePoses,
    cartpole_geometry,
    cartpole_poses,
    is_cartpole,
)
from .common import TIMELINE, Color, join_path, prefix_label
from .documents import metrics_markdown, run_markdown, scenario_markdown, status_markdown
from .readback import read_scalar_series
from .series import SeriesSpec, series_location, series_specs
from .sink import DECIMATED_ROWS, FRAME_HZ, MAX_LATENCY_S, RerunSink
from .stream import DEFAULT_VIEWER_PORT, FLUSH_TIMEOUT_S, PathLike, close_recording, open_recording

__all__ = [
    "CART_SIZE",
    "DECIMATED_ROWS",
    "DEFAULT_POLE_HALF_LENGTH",
    "DEFAULT_VIEWER_PORT",
    "FLUSH_TIMEOUT_S",
    "FRAME_HZ",
    "MAX_LATENCY_S",
    "POLE_RADIUS",
    "TIMELINE",
    "CartPoleGeometry",
    "CartPolePoses",
    "Color",
    "PathLike",
    "RerunSink",
    "SeriesSpec",
    "build_blueprint",
    "cartpole_geometry",
    "cartpole_poses",
    "close_recording",
    "is_cartpole",
    "join_path",
    "metrics_markdown",
    "open_recording",
    "prefix_label",
    "read_scalar_series",
    "run_markdown",
    "scenario_markdown",
    "series_location",
    "series_specs",
    "status_markdown",
]
