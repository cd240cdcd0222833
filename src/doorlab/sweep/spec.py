"""The sweep SPEC: a base scenario, controllers, door states and axes over scenario fields.

Example (every key but ``axes`` optional; unknown keys are errors)::

    base: scenario.yaml              # a scenario file, relative to the SPEC (default: defaults)
    scenario:                        # fields changed on top of the base (a scenario mapping)
      timeline: {extra_time: 1.0}
    controllers: [impedance]         # default: every built-in; a plug-in: FILE.py:NAME
                                     # (relative to the SPEC), MODULE:NAME, an installed one
    doors: [closed]                  # default: the base scenario's
    axes:                            # dotted scenario field -> values
      impedance.kv: [50, 100, 200]                      # a list of values
      station.hinge_damping: {low: 0.2, high: 5, num: 4, log: true}   # a range
      station.cupboard_yaw_error: {low: -15, high: 15, num: 7, unit: deg}   # stored in rad
    samples: 0                       # 0: the full grid; N: N random draws (ranges uniform or
    seed: 0                          #    log-uniform, lists a uniform choice) from ``seed``

Every run is the base scenario with one controller, one door state and one value per axis; a
run is keyed by a hash of its full scenario (:func:`scenario_key`). A SPEC is checked entirely,
every run's scenario included, before anything runs or is written.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed

from doorlab.config import (
    DOOR_STATES,
    Scenario,
    _check_shape,
    load_scenario,
    update_scenario,
    validate,
)
from doorlab.errors import ConfigError
from doorlab.runtime.inputs import (
    load_yaml,
    load_yaml_value,
    quote,
    quote_text,
    read_text_file,
    shorten,
)
from doorlab.sweep.document import SpecDocument

SPEC_KEYS = ("base", "scenario", "controllers", "doors", "axes", "samples", "seed")
RANGE_KEYS = ("low", "high", "num", "log", "unit")
AXIS_UNITS = {"deg": math.pi / 180.0}
"""Units a SPEC may write an axis in, with the factor to the field's own unit (rad)."""
RESERVED_FIELDS = ("controller", "doors", "door_angles")
"""Fields set by ``controllers:`` and ``doors:``, not axes."""
MAX_RUNS = 100_000


@dataclass(frozen=True)
class Axis:
    """One swept scenario field.

    Attributes:
        field: Dotted scenario field, e.g. ``impedance.kv``.
        values: The grid values in the field's unit (a list axis, or a range with ``num``).
        low, high: A range's bounds in the field's unit (None for a list axis).
        log: Draw/space a range log-uniformly.
        unit: The unit the SPEC wrote the axis in ("" = the field's own); plots use it.
        kind: The field's Python type (float, int, str, bool or list).
    """

    field: str
    values: tuple | None
    low: float | None = None
    high: float | None = None
    log: bool = False
    unit: str = ""
    kind: object = float

    @property
    def display_scale(self) -> float:
        """Factor from the field's unit to the SPEC's unit (1 / AXIS_UNITS[unit])."""
        return 1.0 / AXIS_UNITS[self.unit] if self.unit else 1.0

    @property
    def label(self) -> str:
        """Axis label for plots, e.g. ``station.cupboard_yaw_error [deg]``."""
        return f"{self.field} [{self.unit}]" if self.unit else self.field


@dataclass
class SweepSpec:
    """A parsed, validated SPEC (see the module docstring).

    Attributes:
        base: The scenario every run starts from.
        controllers: Controller names. doors: Door states.
        axes: The swept fields, in SPEC order.
        samples: 0 for the full grid, else the number of random draws.
        seed: Seed of the random draws.
    """

    base: Scenario = field(default_factory=Scenario)
    controllers: list[str] = field(default_factory=list)
    doors: list[str] = field(default_factory=list)
    axes: list[Axis] = field(default_factory=list)
    samples: int = 0
    seed: int = 0

    @property
    def is_grid(self) -> bool:
        return self.samples == 0


@dataclass(frozen=True)
class PlannedRun:
    """One run of a sweep: its scenario, swept values and key.

    Attributes:
        index: Position in the sweep (table order).
        key: :func:`scenario_key` of ``scenario``.
        values: Field -> value for each axis (field units).
        scenario: The full scenario.
    """

    index: int
    key: str
    values: dict
    scenario: Scenario


def scenario_key(scenario: Scenario) -> str:
    """A hash of every field of ``scenario`` (16 hex digits): equal scenarios, equal keys."""
    text = json.dumps(dataclasses.asdict(scenario), sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def field_type(dotted: str) -> object:
    """The type of a scenario field named by its dotted path.

    Raises:
        ConfigError: No such field (the message lists the valid ones at that level).
    """
    schema: object = Scenario
    parts = dotted.split(".")
    for depth, part in enumerate(parts):
        if not dataclasses.is_dataclass(schema):
            raise ConfigError(
                f"unknown scenario field {quote(dotted)}: {'.'.join(parts[:depth])} has no fields"
            )
        hints = typing.get_type_hints(schema)
        if part not in hints:
            where = ".".join(parts[:depth]) or "the scenario"
            raise ConfigError(
                f"unknown scenario field {quote(dotted)}; valid fields of {where}: "
                f"{', '.join(hints)}"
            )
        schema = hints[part]
    if dataclasses.is_dataclass(schema):
        raise ConfigError(
            f"{quote(dotted)} is a group of fields; sweep one of: "
            f"{', '.join(f'{dotted}.{k}' for k in typing.get_type_hints(schema))}"
        )
    return schema


def set_field(scenario: Scenario, dotted: str, value: object) -> None:
    """Sets the dotted field of ``scenario`` (in place)."""
    *parents, leaf = dotted.split(".")
    target = scenario
    for part in parents:
        target = getattr(target, part)
    setattr(target, leaf, copy.deepcopy(value))


def get_field(scenario: Scenario, dotted: str) -> object:
    """The value of a dotted field of ``scenario``."""
    target = scenario
    for part in dotted.split("."):
        target = getattr(target, part)
    return target


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _parse_axis(name: object, raw: object, *, grid: bool) -> Axis:
    where = f"axes.{shorten(str(name))}"
    if not isinstance(name, str) or not name:
        raise ConfigError(f"axes: field names must be dotted scenario fields, got {quote(name)}")
    if name in RESERVED_FIELDS:
        raise ConfigError(f"{where}: set {name} with the SPEC's controllers:/doors: lists")
    kind = field_type(name)
    if isinstance(raw, list):
        if not raw:
            raise ConfigError(f"{where} is empty; give at least one value")
        for i, value in enumerate(raw):
            _check_shape(value, kind, f"{where}[{i}]")
        return Axis(name, tuple(raw), kind=kind)
    if not isinstance(raw, dict):
        raise ConfigError(
            f"{where} must be a list of values or a range {{low, high, num, log, unit}}, "
            f"got {quote(raw)}"
        )
    for key in raw:
        if key not in RANGE_KEYS:
            raise ConfigError(
                f"unknown key {where}.{shorten(str(key))}; valid keys of a range: "
                f"{', '.join(RANGE_KEYS)}"
            )
    if kind not in (float, int):
        raise ConfigError(f"{where}: a range needs a numeric field; give a list of values")
    for key in ("low", "high"):
        if key not in raw:
            raise ConfigError(f"{where}.{key} is missing (a range needs low and high)")
        if not _is_number(raw[key]) or not math.isfinite(raw[key]):
            raise ConfigError(f"{where}.{key} must be a number, got {quote(raw[key])}")
    log = raw.get("log", False)
    if not isinstance(log, bool):
        raise ConfigError(f"{where}.log must be true or false, got {quote(log)}")
    unit = raw.get("unit", "")
    if unit not in ("", *AXIS_UNITS):
        raise ConfigError(f"{where}.unit must be one of {', '.join(AXIS_UNITS)}, got {quote(unit)}")
    scale = AXIS_UNITS.get(unit, 1.0)
    low, high = float(raw["low"]) * scale, float(raw["high"]) * scale
    if not low < high:
        raise ConfigError(f"{where}: low must be < high, got {raw['low']} and {raw['high']}")
    if log and low <= 0:
        raise ConfigError(f"{where}: a log range needs low > 0, got {raw['low']}")
    num = raw.get("num")
    if num is not None and (not isinstance(num, int) or isinstance(num, bool) or num < 1):
        raise ConfigError(f"{where}.num must be an integer >= 1, got {quote(num)}")
    values = None
    if num is not None:
        space = np.geomspace if log else np.linspace
        grid_values = space(low, high, num) if num > 1 else np.array([low])
        values = tuple(int(round(v)) if kind is int else float(v) for v in grid_values)
        if kind is int:
            values = tuple(dict.fromkeys(values))
    elif grid:
        raise ConfigError(f"{where}.num is missing: a grid needs the number of values")
    return Axis(name, values, low, high, log, unit, kind)


def _axis_size(raw: object) -> int:
    """How many values an axis of the SPEC has on the grid, read from its YAML alone."""
    if isinstance(raw, list):
        return len(raw)
    if isinstance(raw, dict):
        num = raw.get("num")
        if isinstance(num, int) and not isinstance(num, bool) and num >= 1:
            return num
    return 1  # a malformed axis: _parse_axis names the problem


def check_run_count(
    raw_axes: dict, *, samples: int, controllers: list[str], doors: list[str]
) -> int:
    """The sweep's run count from the SPEC's axes alone (before any value exists).

    Returns:
        The count: controllers x doors x (the grid's points, or ``samples``).

    Raises:
        ConfigError: More than :data:`MAX_RUNS` (the message has the count and its factors).
    """
    if samples:
        factors = [samples]
        what = f"{samples} samples"
    else:
        factors = [_axis_size(raw) for raw in raw_axes.values()]
        shown = [
            f"{size} ({quote_text(str(name))})"
            for name, size in itertools.islice(zip(raw_axes, factors, strict=True), 6)
        ]
        what = " x ".join(shown) + (f" x ... ({len(factors)} axes)" if len(factors) > 6 else "")
    total = len(controllers) * len(doors) * math.prod(factors)
    if total > MAX_RUNS:
        raise ConfigError(
            f"the sweep has {total} runs ({what} x {len(controllers)} controller(s) x "
            f"{len(doors)} door state(s)); at most {MAX_RUNS}: each run is an episode of "
            "seconds, so split the sweep or draw samples:"
        )
    return total


def parse_spec(data: object, *, base_dir: Path | None = None) -> SweepSpec:
    """A :class:`SweepSpec` from a SPEC mapping (already YAML-loaded).

    Args:
        data: The SPEC mapping.
        base_dir: Folder ``base:`` is relative to (default: the working directory).

    Raises:
        ConfigError: Unknown keys, wrong types, unknown fields, empty axes, or a run whose
            scenario is invalid (the message names the dotted field).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"a SPEC must be a mapping with keys {', '.join(SPEC_KEYS)}")
    for key in data:
        if key not in SPEC_KEYS:
            raise ConfigError(f"unknown key {quote(key)}; valid keys: {', '.join(SPEC_KEYS)}")
    from doorlab.episode.controllers import REGISTRY

    # The typed keys: the scenario's shape check (naming the key), then yaml_load_typed.
    typed = {k: v for k, v in data.items() if k not in ("scenario", "axes")}
    _check_shape(typed, SpecDocument, "")
    document = yaml_load_typed(
        schema=SpecDocument, data=yaml.safe_dump(typed), defaults=SpecDocument()
    )
    if document.base:
        path = Path(document.base)
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        base = load_scenario(path)
    else:
        base = Scenario()
    overrides = data.get("scenario")
    if overrides is not None:
        try:
            base = update_scenario(base, yaml.safe_dump(overrides))
        except ConfigError as e:
            raise ConfigError(f"scenario: {e}") from None

    controllers = document.controllers if document.controllers is not None else list(REGISTRY)
    controllers = check_controllers(controllers, base_dir=base_dir)
    doors = document.doors if document.doors is not None else [base.doors]
    for state in doors:
        if state not in DOOR_STATES:
            raise ConfigError(
                f"doors: unknown state {quote(state)}; choose from {', '.join(DOOR_STATES)}"
            )
    for name, values in (("controllers", controllers), ("doors", doors)):
        if not values:
            raise ConfigError(f"{name} is empty; give at least one")
        if len(set(values)) != len(values):
            raise ConfigError(f"{name} lists a value twice: {quote(values)}")
    samples, seed = document.samples, document.seed
    if samples < 0:
        raise ConfigError(
            f"samples must be an integer >= 0 (0: the full grid), got {quote(samples)}"
        )
    if seed < 0:
        raise ConfigError(f"seed must be an integer >= 0, got {quote(seed)}")

    raw_axes = data.get("axes")
    if raw_axes is None or raw_axes == {}:
        raise ConfigError("axes is empty; name at least one scenario field to sweep")
    if not isinstance(raw_axes, dict):
        raise ConfigError(f"axes must map dotted scenario fields to values, got {quote(raw_axes)}")
    check_run_count(raw_axes, samples=samples, controllers=controllers, doors=doors)
    axes = [_parse_axis(name, raw, grid=samples == 0) for name, raw in raw_axes.items()]
    spec = SweepSpec(validate(base), list(controllers), list(doors), axes, samples, seed)
    plan_runs(spec)  # every run's scenario is valid, or this raises now
    return spec


def check_controllers(names: list[str], *, base_dir: Path | None = None) -> list[str]:
    """The SPEC's controllers, each checked and loaded now (a plug-in: imported and its
    signature checked, before anything runs), a plug-in file's relative path made absolute
    against ``base_dir`` (default: the working directory).

    Raises:
        ConfigError: An unknown controller, a plug-in that cannot be used, two that share a
            name (the table's ``controller`` column tells them apart by it).
    """
    from doorlab.config_checks import absolute_controller
    from doorlab.episode.controllers import REGISTRY, controller_name

    out, by_name = [], {}
    for name in names:
        name = absolute_controller(name, base_dir or Path.cwd())
        try:
            shown = controller_name(name)
        except ConfigError as e:
            message = str(e)
            if name not in REGISTRY and ":" not in name and "unknown controller" in message:
                message = f"unknown controller {quote(name)}; choose from {', '.join(REGISTRY)}"
            raise ConfigError(f"controllers: {message}") from None
        if shown in by_name and by_name[shown] != name:
            raise ConfigError(
                f"controllers: {quote(by_name[shown])} and {quote(name)} are both named "
                f"{quote(shown)}; the table tells controllers apart by name"
            )
        by_name[shown] = name
        out.append(name)
    return out


def _check_draft_count(data: dict, axes: dict, prefix: str) -> None:
    """:func:`check_run_count` on a SPEC not yet parsed (controllers and doors as written, or
    their defaults: every controller, one door state)."""
    from doorlab.episode.controllers import REGISTRY

    controllers, doors, samples = (data.get(k) for k in ("controllers", "doors", "samples"))
    try:
        check_run_count(
            axes,
            samples=samples if isinstance(samples, int) and samples > 0 else 0,
            controllers=controllers if isinstance(controllers, list) else list(REGISTRY),
            doors=doors if isinstance(doors, list) else [None],
        )
    except ConfigError as e:
        raise ConfigError(f"{prefix}{e}") from None


def load_spec(
    path: str | Path | None, *, grid: list[str] = (), controllers: list[str] | None = None
) -> SweepSpec:
    """Loads a SPEC file and applies ``--grid KEY=V1,V2,...`` shorthands.

    Args:
        path: The SPEC YAML (None: no file; the axes come from ``grid``).
        grid: ``KEY=V1,V2,...`` items; each adds or replaces the list axis KEY (values YAML).
        controllers: ``--controller`` values: they replace the SPEC's ``controllers``
            (a plug-in file relative to the working directory).

    Raises:
        ConfigError: Missing or invalid file, bad shorthand, invalid SPEC (one line naming
            the file and the dotted field).
    """
    data: dict = {}
    base_dir = None
    prefix = ""
    if path is not None:
        path = Path(path)
        prefix = f"SPEC {str(path)!r}: "
        text = read_text_file(path, what="SPEC file")
        try:
            data = load_yaml(text)
        except ConfigError as e:
            raise ConfigError(f"{prefix}{e}") from None
        data = {} if data is None else data
        base_dir = path.parent
    if grid:
        if not isinstance(data, dict):
            raise ConfigError(f"{prefix}a SPEC must be a mapping")
        axes = dict(data.get("axes") or {}) if isinstance(data.get("axes"), dict) else {}
        texts = {}
        for item in grid:
            key, sep, text = item.partition("=")
            if not sep or not key or not text:
                raise ConfigError(f"--grid expects KEY=V1,V2,... got {quote_text(item)}")
            texts[key] = (item, text.split(","))
        # Counted before any value is parsed (a --grid may list a million values).
        _check_draft_count(data, {**axes, **{k: v for k, (_, v) in texts.items()}}, prefix)
        for key, (item, values) in texts.items():
            try:
                axes[key] = [load_yaml_value(v) for v in values]
            except ConfigError as e:
                raise ConfigError(f"--grid {quote_text(item)}: {e}") from None
        data = {**data, "axes": axes}
    if controllers:
        if not isinstance(data, dict):
            raise ConfigError(f"{prefix}a SPEC must be a mapping")
        from doorlab.config_checks import absolute_controller

        data = {**data, "controllers": [absolute_controller(c, Path.cwd()) for c in controllers]}
    try:
        return parse_spec(data, base_dir=base_dir)
    except ConfigError as e:
        raise ConfigError(f"{prefix}{e}") from None


def _draws(spec: SweepSpec) -> list[tuple]:
    """The axis values of every point: the grid, or ``samples`` random draws."""
    if spec.is_grid:
        return list(itertools.product(*(axis.values for axis in spec.axes)))
    rng = np.random.default_rng(spec.seed)
    columns = []
    for axis in spec.axes:
        if axis.low is not None:
            if axis.log:
                u = rng.uniform(math.log(axis.low), math.log(axis.high), spec.samples)
                draws = np.exp(u)
            else:
                draws = rng.uniform(axis.low, axis.high, spec.samples)
            column = [int(round(v)) if axis.kind is int else float(v) for v in draws]
        else:
            picks = rng.integers(0, len(axis.values), spec.samples)
            column = [axis.values[i] for i in picks]
        columns.append(column)
    return list(zip(*columns, strict=True))


def plan_runs(spec: SweepSpec) -> list[PlannedRun]:
    """Every run of the sweep: controllers x doors x points, each scenario validated.

    Raises:
        ConfigError: A run's scenario is invalid (names the axis values and the field) or two
            runs are identical.
    """
    points = _draws(spec)
    total = len(points) * len(spec.controllers) * len(spec.doors)
    if total > MAX_RUNS:
        raise ConfigError(f"the sweep has {total} runs; more than {MAX_RUNS} is surely a mistake")
    runs: list[PlannedRun] = []
    keys: dict[str, int] = {}
    for controller in spec.controllers:
        for doors in spec.doors:
            for point in points:
                scenario = copy.deepcopy(spec.base)
                scenario.controller = controller
                scenario.doors = doors
                scenario.door_angles = None
                values = {}
                for axis, value in zip(spec.axes, point, strict=True):
                    set_field(scenario, axis.field, value)
                    values[axis.field] = value
                try:
                    validate(scenario)
                except ConfigError as e:
                    shown = ", ".join(f"{k} = {quote(v)}" for k, v in values.items())
                    raise ConfigError(f"axes: the run with {shown}: {e}") from None
                key = scenario_key(scenario)
                if key in keys and not spec.is_grid:
                    continue  # a random draw repeated a point: run it once
                if key in keys:
                    raise ConfigError(
                        f"axes: two runs have the same scenario ({', '.join(map(str, point))}); "
                        "an axis lists a value twice"
                    )
                keys[key] = len(runs)
                runs.append(PlannedRun(len(runs), key, values, scenario))
    return runs
