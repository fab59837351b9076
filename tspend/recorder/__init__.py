"""Rerun recorder: a :class:`~tspend.loop.sinks.Sink` that streams a closed-loop run to Rerun.

What is logged (entity paths relative to the sink's ``prefix``):

- ``info/scenario``, ``info/run``: static markdown at start: the scenario's TOML, seed,
  package version, plant kind, order, dt, ...
- ``info/run`` also holds the run's identity as values (scenario, seed, controller,
  plant kind, version, dt, duration); ``info/columns`` the columns ``tspend export``
  writes (name with the unit at the end, entity, instance)
- ``info/status``, ``info/metrics``: static markdown at :meth:`RerunSink.finish`
- ``events``: a ``TextLog`` at the last time when a run does not complete; ``series/end``
  a cross on the tracking view there, and the domain's drawing writes the reason in 3D
- ``series/state/<name>``: every entry of the plant's full state, every sample, named by
  the domain; ``series/reference``: r and its derivatives
- ``series/<panel>``: multi-instance ``Scalars`` (u and chattering panels with min/max
  aggregation, ``log`` diagnostics as log10), ``series/error_steady`` (the steady-state
  window only), ``series/compensator_share`` (-u_s / b_hat, in u's unit),
  ``series/plant/<extra>``; see :func:`series_specs`
- ``world/...``: the plant's domain draws it (:class:`~tspend.plants.drawing.base.Drawing`):
  the cart-pole's ``world/cart``, ``world/pole`` (a ``Transform3D`` per body at ~50 Hz),
  ``world/rail`` with metre ticks and labelled marks, ``world/cart/readout``; the task's
  bounds (``world/rail/ends``, ``world/cart/bounds``; the Furuta's ``world/arm/bounds``)
- ``crosscheck/verdict``, ``crosscheck/diff/<key>``, ``crosscheck/log10_abs_diff/<key>``:
  the cross-check's verdict, the MuJoCo-minus-ODE series and their log10 |difference|
  (floored at 1e-16, drawn on a fixed range) (:mod:`.crosscheck`)
- ``fuzzy/model/in<j>``, ``fuzzy/compensator/in<j>``: membership curves
  (``LineStrips2D``, one strip per term) and the operating point (``Points2D``);
  ``.../in<j>/initial``: the first curves, faint and behind the adapted ones (static)
- ``fuzzy/firing``, ``fuzzy/compensator_firing``, ``fuzzy/q``: ``BarChart``;
  ``fuzzy/consequents``: ``Tensor`` (k x rule), ``fuzzy/consequent_<k>``: ``BarChart`` per output

Everything time-dependent lives on the ``sim_time`` duration timeline and is sent in
columns with the public ``send_columns`` and the archetypes' ``.columns()``, never row by
row; static data with ``log(..., static=True)``.  A chunk has a fixed cost whatever its
size, so series that share a plot share an entity (multi-instance ``Scalars``); 3D
frames and inner snapshots (50 Hz) are batched ``DECIMATED_ROWS`` at a time; membership
curves are only re-sent when they change.  ``TensorData`` and the membership curves are
built directly in Arrow (:mod:`.arrow`, checked at start-up against the SDK's encoding).

Rerun's 2D views draw y downwards (rerun-io/rerun#1387), so membership curves are
logged with ``y = -mu``: peaks point up on screen.

Where things are:

- :mod:`.sink`: :class:`RerunSink` (the sink protocol) and its snapshot buffer
- :mod:`.stream`: :func:`open_recording` / :func:`close_recording`, viewer spawn/connect
  and their fallbacks
- :mod:`.series`: which per-step series go to which entity (:func:`series_specs`)
- :mod:`.blueprint`: the default viewer layout (:func:`build_blueprint`)
- :mod:`.documents`: the markdown documents (run, scenario, status, metrics), relative paths only
- :mod:`.labels`: physical names and units of a plant's states, control and extras
- :mod:`.fuzzy_axes`: membership-function axes and term labels
- the plant in 3D is its domain's :class:`~tspend.plants.drawing.base.Drawing`
- :mod:`.crosscheck`: the cross-check recording (differences, verdict, layout)
- :mod:`.arrow`: the columns built directly in Arrow
- :mod:`.readback`: reading series back from an ``.rrd`` (:func:`read_scalar_series`)
- :mod:`.common`: the timeline, entity paths and colours they share
"""

from __future__ import annotations

from tspend.recorder.blueprint import build_blueprint
from tspend.recorder.common import TIMELINE, Color, join_path, prefix_label
from tspend.recorder.documents import (metrics_markdown, run_markdown, scenario_markdown,
    status_markdown)
from tspend.recorder.readback import read_scalar_series
from tspend.recorder.series import SeriesSpec, series_location, series_specs
from tspend.recorder.sink import DECIMATED_ROWS, FRAME_HZ, MAX_LATENCY_S, RerunSink
from tspend.recorder.stream import (DEFAULT_VIEWER_PORT, FLUSH_TIMEOUT_S, PathLike,
    close_recording, open_recording)

__all__ = [
    "DECIMATED_ROWS",
    "DEFAULT_VIEWER_PORT",
    "FLUSH_TIMEOUT_S",
    "FRAME_HZ",
    "MAX_LATENCY_S",
    "TIMELINE",
    "Color",
    "PathLike",
    "RerunSink",
    "SeriesSpec",
    "build_blueprint",
    "close_recording",
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
