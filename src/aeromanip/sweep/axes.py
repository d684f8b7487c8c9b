"""What a campaign runs: ``--grid``, ``--random`` and ``--seeds`` turned into a list of runs.

Each run is a set of scenario overrides, the same ``KEY=VALUE`` texts ``--set`` takes
(values read as TOML), plus the scenario variant it flies. Runs are the cartesian product
of the grid axes, then of the random samples (``--samples`` points, each drawing every
``--random`` key), then of the seeds (``--seeds K``: ``physics.seed`` = 0..K-1). The key
``variant`` sweeps the scenario's ``[variants.NAME]``.

A run's id is a hash of its overrides and variant (``run_id``): the same values give the
same id whatever the order of the axes or of the command's options, so a re-run of the
command (or a grown grid) finds the runs already done. Random samples are drawn from a
generator seeded by ``--random-seed``: the same command draws the same values.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import tomli_w

from aeromanip.config import parse_override
from aeromanip.errors import ConfigError

VARIANT_KEY = "variant"  # the swept key that picks the scenario's variant
SEED_KEY = "physics.seed"  # what --seeds sets by default (the physics noise generator)
ID_CHARS = 12  # hex digits of a run id (48 bits: no collision in any real campaign)
MAX_RUNS = 100_000  # runs in one campaign
SIG_DIGITS = 6  # random draws are rounded to this many significant digits (readable ids)


@dataclass(frozen=True)
class Axis:
    """A grid axis: ``key`` takes each of ``values`` (parsed TOML values)."""

    key: str
    values: tuple[Any, ...]
    flag: str = "--grid"


@dataclass(frozen=True)
class RandomAxis:
    """A random axis: ``key`` drawn uniformly in [lo, hi] (integers if both are; ``log``:
    log-uniform)."""

    key: str
    lo: float
    hi: float
    log: bool = False

    @property
    def integer(self) -> bool:
        """Whether draws are integers (both bounds given as integers, not log)."""
        return isinstance(self.lo, int) and isinstance(self.hi, int) and not self.log


@dataclass(frozen=True)
class Run:
    """One run: its id, the swept values (column order), its ``--set`` texts and variant."""

    run_id: str
    values: dict[str, Any]
    overrides: tuple[str, ...]
    variant: str | None


@dataclass(frozen=True)
class SweepSpec:
    """A campaign's axes and fixed settings (see the module docstring)."""

    grid: tuple[Axis, ...] = ()
    random: tuple[RandomAxis, ...] = ()
    samples: int = 0
    random_seed: int = 0
    seeds: int = 0
    seed_key: str = SEED_KEY
    base: tuple[str, ...] = ()  # --set texts applied to every run
    variant: str | None = None  # --variant: every run flies this one

    @property
    def keys(self) -> list[str]:
        """The swept keys, in the order of results.csv's columns."""
        keys = [a.key for a in self.grid] + [a.key for a in self.random]
        return keys + ([self.seed_key] if self.seeds else [])

    def axes(self) -> list[Axis]:
        """The grid axes, then the seeds as one more axis (random samples are not a grid)."""
        seeds = [Axis(self.seed_key, tuple(range(self.seeds)), "--seeds")] if self.seeds else []
        return [*self.grid, *seeds]

    def runs(self) -> list[Run]:
        """Every run, in a fixed order: grid product, random samples, seeds."""
        samples = draw_samples(self.random, self.samples, self.random_seed) or [{}]
        seeds = [{self.seed_key: s} for s in range(self.seeds)] or [{}]
        keys = [a.key for a in self.grid]
        runs = []
        for point in itertools.product(*(a.values for a in self.grid)):
            for sample in samples:
                for seed in seeds:
                    runs.append(self._run(dict(zip(keys, point, strict=True)) | sample | seed))
        return runs

    def _run(self, values: dict[str, Any]) -> Run:
        variant = values.get(VARIANT_KEY, self.variant)
        swept = [f"{k}={toml_value(v)}" for k, v in values.items() if k != VARIANT_KEY]
        overrides = (*self.base, *swept)
        return Run(run_id(overrides, variant), values, overrides, variant)


def toml_value(value: Any) -> str:
    """``value`` written as TOML (what ``--set KEY=...`` reads back as the same value)."""
    return tomli_w.dumps({"v": value}).split("=", 1)[1].strip()


def run_id(overrides: tuple[str, ...] | list[str], variant: str | None) -> str:
    """The stable id of a run: a hash of its overrides (the last one of a key wins, as with
    ``--set``; values compared as parsed, so ``1e-3`` and ``0.001`` are one) and variant."""
    settings = {}
    for text in overrides:
        path, value = parse_override(text)
        settings[".".join(path)] = value
    blob = json.dumps({"set": settings, "variant": variant}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:ID_CHARS]


def split_values(text: str) -> list[str]:
    """Split ``V1,V2,...`` on the commas outside brackets, braces and quotes."""
    parts, depth, quote, cur = [], 0, "", []
    for ch in text:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    parts.append("".join(cur).strip())
    return parts


def _key_of(text: str, flag: str, form: str) -> tuple[str, str]:
    key, sep, rest = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not p.strip() for p in key.split(".")) or not rest.strip():
        raise ConfigError(f"{flag} {text!r}: expected {form} with a dotted KEY")
    return key, rest.strip()


def parse_grid(text: str) -> Axis:
    """``KEY=V1,V2,...`` (each value read as ``--set`` reads it) -> an ``Axis``."""
    key, rest = _key_of(text, "--grid", "KEY=V1,V2,...")
    values = []
    for v in split_values(rest):
        if not v:
            raise ConfigError(f"--grid {key}: an empty value in {rest!r} (values: V1,V2,...)")
        value = parse_override(f"{key}={v}")[1]
        if value in values:
            raise ConfigError(f"--grid {key}: value {v} is given twice")
        values.append(value)
    return Axis(key, tuple(values))


def _number(text: str, key: str, what: str) -> int | float:
    try:
        v = parse_override(f"k={text}")[1]
    except ConfigError:
        v = text
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"--random {key}: {what} {text!r} is not a finite number")
    return v


def parse_random(text: str) -> RandomAxis:
    """``KEY=LO:HI`` (uniform; integers if both are) or ``KEY=LO:HI:log`` (log-uniform,
    0 < LO) -> a ``RandomAxis``."""
    key, rest = _key_of(text, "--random", "KEY=LO:HI or KEY=LO:HI:log")
    parts = rest.split(":")
    if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2].strip() != "log"):
        raise ConfigError(f"--random {key}: {rest!r}: expected LO:HI or LO:HI:log")
    lo, hi = (_number(p.strip(), key, w) for p, w in zip(parts, ("LO", "HI"), strict=False))
    log = len(parts) == 3
    if not lo < hi:
        raise ConfigError(f"--random {key}: LO {lo} must be < HI {hi}")
    if log and lo <= 0:
        raise ConfigError(f"--random {key}: a log range needs 0 < LO, got LO {lo}")
    return RandomAxis(key, lo, hi, log)


def draw_samples(axes: tuple[RandomAxis, ...], n: int, seed: int) -> list[dict[str, Any]]:
    """``n`` points, each drawing every random axis (reproducible from ``seed``)."""
    if not axes:
        return []
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        point: dict[str, Any] = {}
        for a in axes:
            if a.integer:
                point[a.key] = int(rng.integers(a.lo, a.hi, endpoint=True))
            elif a.log:
                x = math.exp(rng.uniform(math.log(a.lo), math.log(a.hi)))
                point[a.key] = float(f"{x:.{SIG_DIGITS}g}")
            else:
                point[a.key] = float(f"{rng.uniform(a.lo, a.hi):.{SIG_DIGITS}g}")
        out.append(point)
    return out


def make_spec(
    grid: list[str] = (),
    random: list[str] = (),
    samples: int | None = None,
    seeds: int | None = None,
    *,
    random_seed: int = 0,
    seed_key: str = SEED_KEY,
    base: list[str] = (),
    variant: str | None = None,
) -> SweepSpec:
    """Parse and check the command's sweep options (``ConfigError`` naming the option)."""
    axes = tuple(parse_grid(t) for t in grid)
    rand = tuple(parse_random(t) for t in random)
    if samples is not None and not rand:
        raise ConfigError(f"--samples {samples}: needs at least one --random KEY=LO:HI")
    if rand and samples is None:
        raise ConfigError(f"--random {rand[0].key}: needs --samples N (how many draws)")
    if samples is not None and not 1 <= samples <= MAX_RUNS:
        raise ConfigError(f"--samples: must be in [1, {MAX_RUNS}], got {samples}")
    if seeds is not None and not 1 <= seeds <= MAX_RUNS:
        raise ConfigError(f"--seeds: must be in [1, {MAX_RUNS}], got {seeds}")
    _key_of(f"{seed_key}=0", "--seed-key", "KEY")
    for text in base:
        parse_override(text)  # KEY=VALUE syntax, before anything else
    spec = SweepSpec(
        axes, rand, samples or 0, random_seed, seeds or 0, seed_key, tuple(base), variant
    )
    _check_keys(spec)
    return spec


def _check_keys(spec: SweepSpec) -> None:
    """Each key swept once, not also fixed by ``--set``, ``variant`` not with ``--variant``;
    something to sweep; not too many runs."""
    if not spec.keys:
        raise ConfigError("sweep: nothing to sweep: give --grid KEY=V1,V2, --random or --seeds")
    seen: set[str] = set()
    for key in spec.keys:
        if key in seen:
            raise ConfigError(f"{key}: swept twice (once per --grid / --random / --seed-key)")
        seen.add(key)
    for text in spec.base:
        key = ".".join(parse_override(text)[0])
        if key in seen:
            raise ConfigError(f"--set {text}: {key} is also swept; drop one of them")
    if VARIANT_KEY in seen and spec.variant is not None:
        raise ConfigError(f"--variant {spec.variant}: the variant is also swept (--grid variant=)")
    n = math.prod(len(a.values) for a in spec.axes()) * max(spec.samples, 1)
    if n > MAX_RUNS:
        raise ConfigError(f"sweep: {n} runs; at most {MAX_RUNS} in one campaign")


def with_variants(spec: SweepSpec, names: list[str]) -> SweepSpec:
    """``spec`` sweeping the scenario's variants ``names`` too (first axis), unless it fixes
    or sweeps one already."""
    if not names or spec.variant is not None or VARIANT_KEY in spec.keys:
        return spec
    return replace(spec, grid=(Axis(VARIANT_KEY, tuple(names)), *spec.grid))
