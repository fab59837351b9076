"""``[randomize]``: the seed draws the initial state and plant parameters.

Without it a seed varies only what the controllers draw (the adaptive controllers' initial
parameters, sensor noise), so a model-based baseline gives the same number at every seed
and "over 20 seeds" is one experiment repeated.  With it each seed is another machine
started from another state::

    [randomize]
    x0 = [{dist = "uniform", low = -0.2, high = 0.2}, {}]       # x0[0] drawn, x0[1] kept
    m  = {dist = "uniform", low = 0.8, high = 1.2, relative = true}
    l  = {dist = "normal", mean = 1.0, std = 0.05, relative = true, low = 0.9, high = 1.1}

Every key names a numeric ``[plant]`` key of the scenario's plant kind (the cart-poles'
``M m l g J gear`` and friction, the chains' own) or ``x0`` (a list of one table per entry,
``{}`` for an entry kept).  On a machine read from its MJCF (the articulated and Furuta
kinds) a key may also name a number of the model by its own body and joint names,
``BODY.mass`` (its inertia scaled with it), ``JOINT.damping`` or ``JOINT.armature``
(:mod:`tspend.plants.articulated.model_numbers`; quoted, ``"link1.mass" = {...}``, or as a
TOML dotted key, ``link1.mass = {...}``)::

    "link1.mass" = {dist = "uniform", low = 0.9, high = 1.1, relative = true}

A distribution is

* ``uniform``: ``low``, ``high`` (``low < high``);
* ``normal``: ``mean``, ``std`` (> 0), optionally truncated to ``[low, high]`` (drawn by
  the inverse CDF, so exactly inside);

absolute by default (the number drawn is the value), or ``relative = true`` (the number
drawn multiplies the nominal: the ``[plant]`` value, or where that is 0 the value the
machine takes itself, :meth:`tspend.plants.domain.Domain.nominal_values`: a MuJoCo
cart-pole's masses, length, gear and friction as its compiled model has them, the ODE's
rod inertia and unit gear, a model's number as its compiled model has it; a relative draw
on a nominal that is 0 even so is refused).
What can be drawn must be a valid value of the key: a positive parameter needs a positive
range (a normal one a ``low``).

Each entry draws from its own numpy Generator seeded by ``(run.seed, STREAM, crc32(name))``:
no stream the controllers or effects draw from moves, a scenario without ``[randomize]``
runs bit for bit as before, and adding an entry leaves the other entries' draws as they
were.  :func:`draw` applies the draws to the scenario's ``[plant]`` before any backend is
built, so the ODE and MuJoCo backends of a domain get the same machine (MuJoCo through
``MjSpec`` edits, read back after compiling: :mod:`tspend.plants.mjcf`).  A model's numbers
go to ``plant.model_values``, written into the model's ``MjSpec`` before it compiles
(:func:`~tspend.plants.articulated.model_numbers.write_values`); both backends are built
from that compiled model, the derived ODE taking the numbers into its parameter vector
(no new derivation).  Their names are checked against the model's bodies and joints when
drawn (the model is known then).  The
controllers are designed on the nominal scenario: a model-based baseline does not know
the draw.  The run's metrics record the draw as ``drawn`` (flat names such as ``m`` and
``x0[0]``), a sweep row as ``drawn.<name>`` columns.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import zlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.plants.registry import domain_of
from tspend.config.tables import Table

if TYPE_CHECKING:
    from tspend.config import PlantConfig, Scenario

__all__ = ["Draw", "Drawn", "DISTRIBUTIONS", "STREAM", "draw", "draw_values", "first_uniforms",
           "read_randomize", "randomizable", "takes_model_values"]

#: the distributions a ``[randomize]`` entry may name
DISTRIBUTIONS = ("uniform", "normal")
#: the stream tag of the draws (the effects' noise uses 0x5E4502, controllers the bare seed)
STREAM = 0x7A4D0
#: float ``[plant]`` keys that are settings of the simulation, not of the machine
NOT_DRAWN = ("state_bound", "timestep")
_KEYS = {"uniform": ("dist", "low", "high", "relative"),
         "normal": ("dist", "mean", "std", "low", "high", "relative")}


@dataclass(frozen=True)
class Draw:
    """One drawn quantity: ``name`` is a ``[plant]`` key or ``x0[i]``."""

    name: str
    dist: str
    a: float                     #: uniform: low; normal: mean
    b: float                     #: uniform: high; normal: std
    relative: bool = False
    low: float = -math.inf       #: normal: truncation (uniform: = a)
    high: float = math.inf       #: normal: truncation (uniform: = b)

    def sample(self, rng: np.random.Generator, nominal: float) -> float:
        """One value: a single uniform number from ``rng``, mapped through the quantile
        function (of the truncated normal for ``normal``), times ``nominal`` if relative."""
        return float(self.value_at(np.float64(rng.random()), nominal))

    def value_at(self, q: Any, nominal: Any) -> Any:
        """The value (or values: ``q`` an array) at the uniform number(s) ``q``:
        :meth:`sample`'s map, one text for one seed and for many (:func:`draw_values`)."""
        from scipy.special import ndtr, ndtri

        if self.dist == "uniform":
            width = self.b - self.a
            v = (self.a + q * width if math.isfinite(width)
                 else self.a * (1.0 - q) + self.b * q)  # a range wider than a double
            v = np.minimum(np.maximum(v, self.a), self.b)
        else:
            lo = ndtr((self.low - self.a) / self.b)
            hi = ndtr((self.high - self.a) / self.b)
            v = self.a + self.b * ndtri(lo + q * (hi - lo))
            v = np.minimum(np.maximum(v, self.low), self.high)  # the quantile's last rounding
        return v * nominal if self.relative else v

    def bounds(self, nominal: float) -> tuple[float, float]:
        """The interval every value lies in."""
        lo, hi = (self.a, self.b) if self.dist == "uniform" else (self.low, self.high)
        if self.relative:
            lo, hi = sorted((lo * nominal, hi * nominal))
        return lo, hi


@dataclass(frozen=True)
class Drawn:
    """The scenario with its draws applied to ``[plant]``, and the draws by name."""

    scenario: Any
    values: dict[str, float]


def randomizable(cfg: "PlantConfig") -> tuple[str, ...]:
    """The ``[plant]`` keys of ``cfg``'s kind a ``[randomize]`` table may name."""
    return tuple(f.name for f in dataclasses.fields(cfg)
                 if isinstance(f.default, float) and not isinstance(f.default, bool)
                 and f.name not in NOT_DRAWN) + ("x0",)


def takes_model_values(cfg: "PlantConfig") -> bool:
    """Whether ``cfg``'s kind reads its machine from an MJCF whose numbers a draw may name
    (``BODY.mass``, ``JOINT.damping``, ``JOINT.armature``: the articulated and Furuta kinds)."""
    return any(f.name == "model_values" for f in dataclasses.fields(cfg))


def _entries(r: Table, cfg: "PlantConfig", allowed: tuple[str, ...]) -> list[tuple[str, Any]]:
    """``(name, value)`` of the table's entries, a model's names flattened: TOML reads
    ``link1.mass = {...}`` as ``link1 = {mass = {...}}``, ``"link1.mass" = {...}`` as one
    key.  Where both give the same name the dotted one's keys update the quoted one's (what
    ``--set randomize.link1.mass.low=0.8`` does to a file that quotes the name)."""
    from tspend.plants.articulated.model_numbers import QUANTITIES, split

    model = takes_model_values(cfg)
    out: dict[str, Any] = {}
    for key, value in r.table.items():
        if model and key not in allowed and isinstance(value, dict) and value \
                and "dist" not in value:
            for q, v in value.items():
                name = f"{key}.{q}"
                old = out.get(name)
                out[name] = {**old, **v} if isinstance(old, dict) and isinstance(v, dict) else v
        elif isinstance(out.get(key), dict) and isinstance(value, dict):
            out[key] = {**value, **out[key]}
        else:
            out[key] = value
    for name in out:
        if name in allowed or (model and split(name) is not None):
            continue
        close = difflib.get_close_matches(name, allowed, n=1)
        did = f" (did you mean '{close[0]}'?)" if close else ""
        more = (f", or {' '.join(f'{k.upper()}.{q}' for q, k in QUANTITIES.items())} named "
                f"by the model's bodies and joints") if model else ""
        raise r.error(name, f"unknown key{did}; allowed for plant kind '{cfg.kind}': "
                            f"{', '.join(allowed)} (numeric [plant] keys and x0){more}")
    return list(out.items())


def read_randomize(r: Table, cfg: "PlantConfig") -> tuple[Draw, ...]:
    """The ``[randomize]`` table of a scenario whose ``[plant]`` is ``cfg``, checked (a
    model's names against its bodies and joints when drawn: :func:`draw`)."""
    from tspend.plants.articulated.model_numbers import LOWER_BOUNDS, split

    allowed = randomizable(cfg)
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    draws: list[Draw] = []
    for key, value in _entries(r, cfg, allowed):
        if key == "x0":
            entries = value
            n = len(cfg.x0)
            if not isinstance(entries, list) or len(entries) != n or \
                    not all(isinstance(e, dict) for e in entries):
                raise r.error(key, f"must be a list of {n} tables (one per entry of x0, {{}} "
                                   f"for an entry kept), got {entries!r}")
            for i, e in enumerate(entries):
                if e:
                    name = f"x0[{i}]"
                    sub = Table(r.path, e, f"{r.prefix}{name}.")
                    draws.append(_read_one(sub, name, cfg.x0[i], None, False))
            continue
        if not isinstance(value, dict):
            raise r.error(key, f"must be a table such as {{dist = \"uniform\", low = 0.9, "
                               f"high = 1.1}}, got {value!r}")
        sub = Table(r.path, value, f"{r.prefix}{key}.")
        if key not in fields:
            # a model's number: its bound is the quantity's, its nominal known when drawn
            low, strict = LOWER_BOUNDS[split(key)[1]]  # type: ignore[index]
            draws.append(_read_one(sub, key, 0.0, low, strict))
            continue
        meta = fields[key].metadata
        # a key whose 0 is the machine's own value (metadata ``own``) cannot be drawn 0
        draws.append(_read_one(sub, key, float(getattr(cfg, key)), meta.get("low"),
                               bool(meta.get("strict", False) or meta.get("own", False))))
    return tuple(draws)


def _read_one(t: Table, name: str, nominal: float, low: float | None, strict: bool) -> Draw:
    dist = t.string("dist", None, DISTRIBUTIONS)
    t.check_keys(_KEYS[dist], f"for dist '{dist}'")
    relative = t.boolean("relative", False)
    if dist == "uniform":
        a, b = t.number("low"), t.number("high")
        if not a < b:
            raise t.error("low", f"must be < high, got low = {a:g}, high = {b:g}")
        d = Draw(name, dist, a, b, relative, a, b)
    else:
        mean, std = t.number("mean"), t.number("std", low=0.0, strict=True)
        lo = t.number("low") if t.has("low") else -math.inf
        hi = t.number("high") if t.has("high") else math.inf
        if not lo < hi:
            raise t.error("low", f"must be < high, got low = {lo:g}, high = {hi:g}")
        if not lo <= mean <= hi:
            raise t.error("mean", f"must lie in [low, high] = [{lo:g}, {hi:g}], got {mean:g}")
        d = Draw(name, dist, mean, std, relative, lo, hi)
    if low is not None:
        # a 0 nominal is the machine's own value, known once it is built (draw): the
        # parameters with a lower bound are >= 0, so its sign is that of 1
        lo, hi = d.bounds(nominal if nominal != 0.0 or not relative else 1.0)
        bad = lo <= low if strict else lo < low
        if bad:
            need = f"{'>' if strict else '>='} {low:g}"
            what = ("give low" if dist == "normal" else "raise low") + " so that it cannot"
            raise t.error("low" if t.has("low") or dist == "uniform" else "dist",
                          f"{name} must be {need}, but the draw can give {lo:g}; {what}")
    return d


def _machine_values(scenario: "Scenario") -> dict[str, float]:
    """The values the scenario's machine takes for its ``[plant]`` keys left at 0."""
    return domain_of(scenario.plant.kind).nominal_values(scenario)


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng((seed, STREAM, zlib.crc32(name.encode())))


def _nominals(scenario: "Scenario") -> list[tuple[Draw, float]]:
    """Each draw of the scenario's ``[randomize]`` with the nominal a relative draw
    multiplies (x0's entry, the ``[plant]`` value, or the machine's own where that is 0);
    ScenarioError for a model's name the model lacks or a relative draw on a 0."""
    from tspend.plants.articulated.model_numbers import check_names

    draws = scenario.randomize
    cfg = scenario.plant
    fields = {f.name for f in dataclasses.fields(cfg)}
    own: dict[str, float] | None = None
    out = []
    for d in draws:
        if d.name.startswith("x0["):
            out.append((d, cfg.x0[int(d.name[3:-1])]))
            continue
        in_plant = d.name in fields
        nominal = float(getattr(cfg, d.name)) if in_plant else 0.0
        if not in_plant and own is None:
            own = _machine_values(scenario)
            model = domain_of(cfg.kind).model_file(cfg)
            check_names([e.name for e in draws if e.name not in fields
                         and not e.name.startswith("x0[")], own,
                        f"{scenario.path} (model {model})")
        if d.relative and nominal == 0.0:
            if own is None:
                own = _machine_values(scenario)
            nominal = float(own.get(d.name, 0.0))
            if nominal == 0.0:
                what = "[plant] value" if in_plant else "model's value"
                raise ScenarioError(
                    f"{scenario.path}: randomize.{d.name}.relative: the {what} of "
                    f"{d.name} is 0 and so is the machine's own, so a relative draw is always "
                    f"0: give a nominal value or draw it absolute")
        out.append((d, nominal))
    return out


def draw(scenario: "Scenario") -> Drawn:
    """The scenario's ``[randomize]`` drawn with its ``run.seed``, applied to ``[plant]``
    (the same scenario and ``{}`` when it has none).  A model's number goes to
    ``plant.model_values``, which the backends write into the MJCF before compiling."""
    if not scenario.randomize:
        return Drawn(scenario, {})
    cfg = scenario.plant
    fields = {f.name for f in dataclasses.fields(cfg)}
    x0 = list(cfg.x0)
    changes: dict[str, Any] = {}
    model_values: list[tuple[str, float]] = []
    values: dict[str, float] = {}
    for d, nominal in _nominals(scenario):
        values[d.name] = v = d.sample(_rng(scenario.run.seed, d.name), nominal)
        if d.name.startswith("x0["):
            x0[int(d.name[3:-1])] = v
        elif d.name in fields:
            changes[d.name] = v
        else:
            model_values.append((d.name, v))
    if model_values:
        changes["model_values"] = tuple(model_values)
    plant = dataclasses.replace(cfg, x0=tuple(x0), **changes)
    return Drawn(dataclasses.replace(scenario, plant=plant), values)


def draw_values(scenario: "Scenario", seeds: Any) -> dict[str, np.ndarray]:
    """What :func:`draw` draws at each of ``seeds`` (name -> one value per seed, equal to
    ``draw(scenario at that seed).values``) as arrays: each seed's first uniform number of
    its entry's stream computed for all seeds at once (:func:`first_uniforms`)."""
    seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
    return {d.name: d.value_at(first_uniforms(seeds, d.name), nominal)
            for d, nominal in _nominals(scenario)}


# -- numpy's Generator seeded by a tuple, for many seeds at once ---------------------------
# default_rng((seed, STREAM, crc)).random() is SeedSequence's hash of the three words into
# a PCG64 state, one step of PCG64 (XSL-RR output) and its top 53 bits (numpy's
# bit_generator.pyx, pcg64.h).  Written over uint64 arrays, so 10^5 seeds take
# milliseconds, not the seconds 10^5 Generators take; tests/test_randomize.py checks it
# against numpy's own Generator.
_M32 = np.uint64(0xFFFFFFFF)
_HASH_A, _MULT_A, _HASH_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_PCG_MULT = (np.uint64(2549297995355413924), np.uint64(4865540595714422341))


def _xshift(v: np.ndarray) -> np.ndarray:
    return v ^ (v >> np.uint64(16))


def _pool(words: list[np.ndarray]) -> list[np.ndarray]:
    """SeedSequence's pool of 4 words from the entropy ``words`` (mix_entropy)."""
    const = _HASH_A

    def hashmix(v: np.ndarray) -> np.ndarray:
        nonlocal const
        v = v ^ np.uint64(const)
        const = (const * _MULT_A) & 0xFFFFFFFF
        return _xshift((v * np.uint64(const)) & _M32)

    def mix(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return _xshift((((x * np.uint64(_MIX_L)) & _M32) + np.uint64(1 << 32)
                        - ((y * np.uint64(_MIX_R)) & _M32)) & _M32)

    mixer = [hashmix(words[i] if i < len(words) else np.zeros_like(words[0])) for i in range(4)]
    for src in range(4):
        for dst in range(4):
            if src != dst:
                mixer[dst] = mix(mixer[dst], hashmix(mixer[src]))
    for src in range(4, len(words)):
        for dst in range(4):
            mixer[dst] = mix(mixer[dst], hashmix(words[src]))
    return mixer


def _state_words(pool: list[np.ndarray]) -> list[np.ndarray]:
    """SeedSequence.generate_state(4, uint64) from the pool."""
    const, half = _HASH_B, []
    for i in range(8):
        v = pool[i % 4] ^ np.uint64(const)
        const = (const * _MULT_B) & 0xFFFFFFFF
        half.append(_xshift((v * np.uint64(const)) & _M32))
    return [half[2 * k] | (half[2 * k + 1] << np.uint64(32)) for k in range(4)]


def _pcg_step(hi: np.ndarray, lo: np.ndarray, inc_hi: np.ndarray,
              inc_lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """state * multiplier + increment, modulo 2^128, on (high, low) 64-bit halves."""
    m_hi, m_lo = _PCG_MULT
    a0, a1, b0, b1 = lo & _M32, lo >> np.uint64(32), m_lo & _M32, m_lo >> np.uint64(32)
    p00, p01, p10, p11 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    mid = (p00 >> np.uint64(32)) + (p01 & _M32) + (p10 & _M32)
    prod_lo = (p00 & _M32) | (mid << np.uint64(32))
    prod_hi = (p11 + (p01 >> np.uint64(32)) + (p10 >> np.uint64(32)) + (mid >> np.uint64(32))
               + hi * m_lo + lo * m_hi)
    new_lo = prod_lo + inc_lo
    return prod_hi + inc_hi + (new_lo < prod_lo).astype(np.uint64), new_lo


def first_uniforms(seeds: np.ndarray, name: str) -> np.ndarray:
    """``_rng(seed, name).random()`` for every seed (the first number of each seed's
    stream for entry ``name``); seeds outside [0, 2^32) one Generator each."""
    seeds = np.asarray(seeds, dtype=np.int64)
    if seeds.size and not (seeds.min() >= 0 and seeds.max() < 1 << 32):
        return np.array([_rng(int(s), name).random() for s in seeds])
    with np.errstate(over="ignore"):
        words = [seeds.astype(np.uint64), np.full(seeds.shape, STREAM, dtype=np.uint64),
                 np.full(seeds.shape, zlib.crc32(name.encode()), dtype=np.uint64)]
        init_hi, init_lo, seq_hi, seq_lo = _state_words(_pool(words))
        inc_hi = (seq_hi << np.uint64(1)) | (seq_lo >> np.uint64(63))
        inc_lo = (seq_lo << np.uint64(1)) | np.uint64(1)
        zero = np.zeros_like(inc_lo)
        hi, lo = _pcg_step(zero, zero, inc_hi, inc_lo)          # pcg64 srandom: state 0, step,
        new_lo = lo + init_lo                                   # add the initial state, step
        hi, lo = _pcg_step(hi + init_hi + (new_lo < lo).astype(np.uint64), new_lo, inc_hi, inc_lo)
        hi, lo = _pcg_step(hi, lo, inc_hi, inc_lo)              # the first draw: step, output
        x, rot = hi ^ lo, hi >> np.uint64(58)
        out = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return (out >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)
