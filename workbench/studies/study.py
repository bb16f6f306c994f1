"""Studies as data: a base scenario and instrument, axes over any of their parameters, repeats with seeds.

A study file (TOML or JSON)::

    [study]
    name = "noise x subset"
    repeats = 3                 # seeds scenario.seed + 0, 1, 2 (or: seeds = [4, 9, 11])
    mode = "factorial"          # every combination of the axes; "cases": the [[case]] list below
    metrics = ["random_error_px", "predicted_error_px"]   # optional: default every metric of the experiment

    [scenario]                  # the base scenario (workbench.scenario.Scenario); absent keys: defaults
    experiment = "dic2d"
    [scenario.render]
    read_noise_grey = 1.0

    [instrument]                # the base instrument (workbench.scenario.Instrument)
    step_px = 12

    [[axis]]
    name = "noise_grey"                            # dimension name in the results
    parameter = "scenario.render.read_noise_grey"  # any scenario.* or instrument.* parameter
    values = [0.5, 1.0, 2.0]

    [[case]]                    # mode = "cases": each case sets any parameters
    name = "stage scale 0.5 %"
    set = { "scenario.motion.stage_scale_error" = 0.005 }

Everything is checked before any work starts: unknown keys, wrong types, an axis over a parameter that does
not exist or a value that does not fit it, each refused with :class:`workbench.config.ConfigError` naming the
file and the key.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path

from workbench.config import ConfigError, from_dict, get_value, read_mapping, with_value
from workbench.scenario import Instrument, Scenario, case_hash

STUDY_KEYS = {"name", "description", "repeats", "seeds", "mode", "metrics"}
AXIS_KEYS = {"name", "parameter", "values"}
CASE_KEYS = {"name", "set"}
TOP_KEYS = {"study", "scenario", "instrument", "axis", "case", "budget"}


@dataclass(frozen=True)
class Axis:
    """One dimension of a factorial study: ``parameter`` (dotted, ``scenario.`` or ``instrument.``) takes ``values``."""

    name: str
    parameter: str
    values: tuple


@dataclass(frozen=True)
class CaseSpec:
    """One listed case: a name and the parameters it sets."""

    name: str
    assignments: tuple[tuple[str, object], ...]


@dataclass(frozen=True)
class Case:
    """One unit of work: a scenario and instrument fully resolved, its labels on the study's dimensions."""

    scenario: Scenario
    instrument: Instrument
    labels: dict
    seed: int
    hash: str = ""


@dataclass(frozen=True)
class Study:
    """A parsed study file (see the module doc)."""

    name: str
    scenario: Scenario
    instrument: Instrument
    mode: str = "factorial"
    axes: tuple[Axis, ...] = ()
    cases: tuple[CaseSpec, ...] = ()
    seeds: tuple[int, ...] = (0,)
    metrics: tuple[str, ...] = ()
    description: str = ""
    source: str = ""
    source_text: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def dims(self) -> tuple[str, ...]:
        """Dimensions of the results, ``repeat`` last."""
        return (tuple(a.name for a in self.axes) if self.mode == "factorial" else ("case",)) + ("repeat",)

    def expand(self) -> list[Case]:
        """Every case of the study (factorial product or listed cases) times every seed."""
        out = []
        if self.mode == "factorial":
            combos = [dict(zip([a.name for a in self.axes], values))
                      for values in itertools.product(*[a.values for a in self.axes])]
            settings = [[(a.parameter, combo[a.name]) for a in self.axes] for combo in combos]
        else:
            combos = [{"case": c.name} for c in self.cases]
            settings = [list(c.assignments) for c in self.cases]
        for labels, assignments in zip(combos, settings):
            for repeat, seed in enumerate(self.seeds):
                scenario, instrument = apply_assignments(self.scenario, self.instrument,
                                                         assignments + [("scenario.seed", seed)], self.source)
                out.append(Case(scenario, instrument, {**labels, "repeat": repeat}, seed,
                                case_hash(scenario, instrument)))
        return out


def apply_assignments(scenario: Scenario, instrument: Instrument, assignments, where: str = ""):
    """Set dotted ``scenario.*`` / ``instrument.*`` parameters; errors name ``where`` and the parameter."""
    for path, value in assignments:
        root, _, rest = path.partition(".")
        try:
            if root == "scenario" and rest:
                scenario = with_value(scenario, rest, value)
                continue
            if root == "instrument" and rest:
                instrument = with_value(instrument, rest, value)
                continue
        except ConfigError as err:
            raise ConfigError(f"{where}: {root}.{err}") from None
        raise ConfigError(f"{where}: {path}: a parameter starts with 'scenario.' or 'instrument.' "
                          f"(e.g. scenario.render.read_noise_grey, instrument.subset_px)")
    return scenario, instrument


def _check_keys(table, allowed: set, where: str) -> None:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        key = f"{where}.{unknown[0]}" if where else unknown[0]
        raise ConfigError(f"{key}: unknown key (known: {', '.join(sorted(allowed))})")


def _typed(table: dict, key: str, types, where: str, default=None):
    value = table.get(key, default)
    if value is None:
        return None
    if isinstance(value, bool) and bool not in (types if isinstance(types, tuple) else (types,)):
        raise ConfigError(f"{where}.{key}: expected {getattr(types, '__name__', types)}, got {value!r}")
    if not isinstance(value, types):
        name = types.__name__ if isinstance(types, type) else " or ".join(t.__name__ for t in types)
        raise ConfigError(f"{where}.{key}: expected {name}, got {value!r}")
    return value


def parse_study(data: dict, source: str = "study", source_text: str = "") -> Study:
    """A :class:`Study` from a mapping (a parsed study file); every error names ``source`` and the key."""
    try:
        return _parse(data, source, source_text)
    except ConfigError as err:
        text = str(err)
        raise ConfigError(text if text.startswith(f"{source}:") else f"{source}: {text}") from None


def _parse(data: dict, source: str, source_text: str) -> Study:
    _check_keys(data, TOP_KEYS, "")
    head = data.get("study", {})
    _check_keys(head, STUDY_KEYS, "study")
    name = _typed(head, "name", str, "study", default=Path(source).stem)
    mode = _typed(head, "mode", str, "study", default="factorial")
    if mode not in ("factorial", "cases"):
        raise ConfigError(f"study.mode: must be 'factorial' or 'cases', got {mode!r}")
    scenario = from_dict(Scenario, data.get("scenario", {}), "scenario")
    instrument = from_dict(Instrument, data.get("instrument", {}), "instrument")
    if "seeds" in head and "repeats" in head:
        raise ConfigError("study.seeds: give either repeats or seeds, not both")
    if "seeds" in head:
        seeds = _typed(head, "seeds", list, "study")
        if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
            raise ConfigError(f"study.seeds: expected a non-empty list of non-negative integers, got {seeds!r}")
        if len(set(seeds)) != len(seeds):
            raise ConfigError(f"study.seeds: seeds must differ, got {seeds!r}")
    else:
        repeats = _typed(head, "repeats", int, "study", default=1)
        if repeats < 1:
            raise ConfigError(f"study.repeats: must be >= 1, got {repeats}")
        seeds = [scenario.seed + r for r in range(repeats)]
    metrics = _typed(head, "metrics", list, "study", default=[])
    if not all(isinstance(m, str) for m in metrics):
        raise ConfigError(f"study.metrics: expected a list of metric names, got {metrics!r}")
    from workbench.studies.cases import experiment_metrics
    known = experiment_metrics(scenario.experiment)
    bad = [m for m in metrics if m not in known]
    if bad:
        raise ConfigError(f"study.metrics: {bad[0]!r} is not a metric of the {scenario.experiment} experiment "
                          f"(its metrics: {', '.join(known)})")

    axes, cases = [], []
    raw_axes = data.get("axis", [])
    if not isinstance(raw_axes, list):
        raise ConfigError("axis: expected [[axis]] tables")
    for i, raw in enumerate(raw_axes):
        where = f"axis[{i}]"
        _check_keys(raw, AXIS_KEYS, where)
        for key in ("name", "parameter", "values"):
            if key not in raw:
                raise ConfigError(f"{where}.{key}: missing")
        axis_name = _typed(raw, "name", str, where)
        parameter = _typed(raw, "parameter", str, where)
        values = _typed(raw, "values", list, where)
        if not values:
            raise ConfigError(f"{where}.values: an axis needs at least one value")
        for value in values:                 # every value must fit its parameter, before any work
            apply_assignments(scenario, instrument, [(parameter, value)], f"{where} ({axis_name})")
        if axis_name in ("repeat", "case") or axis_name in [a.name for a in axes]:
            raise ConfigError(f"{where}.name: {axis_name!r} is reserved or used twice")
        axes.append(Axis(axis_name, parameter, tuple(values)))
    raw_cases = data.get("case", [])
    if not isinstance(raw_cases, list):
        raise ConfigError("case: expected [[case]] tables")
    for i, raw in enumerate(raw_cases):
        where = f"case[{i}]"
        _check_keys(raw, CASE_KEYS, where)
        case_name = _typed(raw, "name", str, where, default=f"case {i}")
        assignments = _typed(raw, "set", dict, where, default={})
        apply_assignments(scenario, instrument, list(assignments.items()), f"{where} ({case_name})")
        cases.append(CaseSpec(case_name, tuple(assignments.items())))
    if mode == "factorial" and cases:
        raise ConfigError("case: [[case]] tables need study.mode = \"cases\"")
    if mode == "cases" and axes:
        raise ConfigError("axis: [[axis]] tables need study.mode = \"factorial\"")
    if mode == "cases" and not cases:
        raise ConfigError("case: study.mode = \"cases\" needs at least one [[case]]")
    if len({c.name for c in cases}) != len(cases):
        raise ConfigError("case: case names must differ")
    return Study(name=name, scenario=scenario, instrument=instrument, mode=mode, axes=tuple(axes),
                 cases=tuple(cases), seeds=tuple(seeds), metrics=tuple(metrics),
                 description=_typed(head, "description", str, "study", default=""), source=source,
                 source_text=source_text, extra={"budget": data.get("budget")} if "budget" in data else {})


def load_study(path: str | Path) -> Study:
    """Read and check a study file (TOML or JSON); errors name the file and the key."""
    path = Path(path)
    data = read_mapping(path)
    study = parse_study(data, str(path), path.read_text(encoding="utf-8"))
    check_cases(study)
    return study


def check_cases(study: Study) -> None:
    """The experiment's own checks on every case (e.g. what it can render), before any work starts."""
    from workbench.studies.cases import experiment_module

    module = experiment_module(study.scenario.experiment)
    for case in study.expand():
        try:
            module.check(case.scenario, case.instrument)
        except ValueError as err:
            labels = ", ".join(f"{k} = {v}" for k, v in case.labels.items() if k != "repeat")
            raise ConfigError(f"{study.source}: case {labels or 'base'}: {err}") from None


__all__ = ["Axis", "Case", "CaseSpec", "Study", "apply_assignments", "get_value", "load_study", "parse_study"]
