"""Configs as data: frozen dataclasses that load from and save to TOML/JSON, with a schema and a content hash.

Every field of a config dataclass is one of: ``bool``, ``int``, ``float``, ``str``, a tuple of floats or ints
(``tuple[float, ...]`` or a fixed length ``tuple[float, float, float]``), ``X | None`` of those (``None`` =
absent in TOML, which has no null), a nested config dataclass, or ``tuple[Config, ...]`` (an array of tables,
``[[camera]]`` in TOML; its items' keys are named ``camera[0].pixel_pitch_um``). A field may restrict its values with
``metadata={"choices": (...)}`` or bound them with ``metadata={"min": ..., "max": ...}`` and document its unit
and source with ``metadata={"doc": ...}``.

Loading is strict (DESIGN §8): an unknown key, a wrong type, a non-finite number or a value outside the
field's choices or bounds is refused with a :class:`ConfigError` naming the file and the dotted key
(``study.toml: scenario.render.spp: expected an integer, got 'many'``); nothing is coerced except an
integer given for a float and a list given for a tuple. A config's hash is the SHA-256 of its canonical
JSON (sorted keys, floats as floats), so equal configs have equal hashes whatever file they came from.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
import types
import typing
from pathlib import Path

from labio.atomic import atomic_write_text


class ConfigError(ValueError):
    """A config file or value that does not fit its schema; the message names the file and the key."""


# ------------------------------------------------------------------------------------------------------------
def _hints(cls) -> dict:
    return typing.get_type_hints(cls)


def _is_config(tp) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _optional_inner(tp):
    """``X`` for ``X | None``, else None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(tp)) == 2:
            return args[0]
    return None


def _table_array_item(tp):
    """The item config of ``tuple[Config, ...]`` (an array of tables), else None."""
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis and _is_config(args[0]):
            return args[0]
    return None


def _describe(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _number(value, tp, key: str, meta) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{key}: expected {'an integer' if tp is int else 'a number'}, got {_describe(value)}")
    if tp is int and not isinstance(value, int):
        raise ConfigError(f"{key}: expected an integer, got {_describe(value)}")
    if not math.isfinite(value):
        raise ConfigError(f"{key}: must be finite, got {value!r}")
    value = float(value) if tp is float else int(value)
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{key}: must be one of {', '.join(map(repr, choices))}; got {value!r}")
    lo, hi = meta.get("min"), meta.get("max")
    if lo is not None and value < lo:
        raise ConfigError(f"{key}: must be >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ConfigError(f"{key}: must be <= {hi}, got {value!r}")
    return value


def coerce_value(value, tp, key: str, meta=None):
    """``value`` checked against the annotation ``tp`` (see the module doc); raises :class:`ConfigError`."""
    meta = meta or {}
    inner = _optional_inner(tp)
    if inner is not None:
        return None if value is None else coerce_value(value, inner, key, meta)
    if _is_config(tp):
        if isinstance(value, tp):
            return value
        return from_dict(tp, value, key)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {_describe(value)}")
        return value
    if tp in (int, float):
        return _number(value, tp, key, meta)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {_describe(value)}")
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(f"{key}: must be one of {', '.join(map(repr, choices))}; got {value!r}")
        return value
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {_describe(value)}")
        if len(args) == 2 and args[1] is Ellipsis and _is_config(args[0]):
            # an array of tables ([[camera]] in TOML): each item a config of its own
            if not value and meta.get("min_items"):
                raise ConfigError(f"{key}: give at least {meta['min_items']} (an array of tables, [[{key.split('.')[-1]}]])")
            return tuple(v if isinstance(v, args[0]) else from_dict(args[0], v, f"{key}[{i}]")
                         for i, v in enumerate(value))
        if len(args) == 2 and args[1] is Ellipsis:
            item_types = [args[0]] * len(value)
        else:
            if len(value) != len(args):
                raise ConfigError(f"{key}: expected a list of {len(args)} values, got {len(value)}")
            item_types = list(args)
        return tuple(_number(v, t, f"{key}[{i}]", meta) for i, (v, t) in enumerate(zip(value, item_types)))
    raise TypeError(f"unsupported config annotation {tp!r} at {key}")   # a programming error, not user input


def from_dict(cls, data, where: str = ""):
    """Build the config dataclass ``cls`` from a (TOML/JSON) mapping; absent keys take their defaults.

    ``where`` is the dotted prefix of the keys in messages (e.g. ``"scenario"``).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where or 'config'}: expected a table of keys, got {_describe(data)}")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = [k for k in data if k not in fields]
    if unknown:
        prefix = f"{where}." if where else ""
        raise ConfigError(f"{prefix}{unknown[0]}: unknown key (known keys of {where or cls.__name__}: "
                          f"{', '.join(sorted(fields))})")
    values = {}
    for name, value in data.items():
        key = f"{where}.{name}" if where else name
        values[name] = coerce_value(value, hints[name], key, fields[name].metadata)
    try:
        return cls(**values)
    except ConfigError:
        raise
    except (ValueError, TypeError) as err:       # a cross-field check of the dataclass itself
        raise ConfigError(f"{where or cls.__name__}: {err}") from None


#: Bump when a default value changes meaning (hashes leave defaults out, see :func:`canonical_json`).
SCHEMA_VERSION = 1


def _default_of(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def to_dict(config, skip_defaults: bool = False) -> dict:
    """Plain mapping of a config (tuples as lists, ``None`` fields left out: TOML has no null).

    ``skip_defaults``: also leave out every value equal to its field's default (nested tables that are all
    default vanish).
    """
    out = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if value is None:
            continue
        if skip_defaults and value == _default_of(f):
            continue
        if dataclasses.is_dataclass(value):
            value = to_dict(value, skip_defaults)
            if skip_defaults and not value:
                continue
        elif isinstance(value, tuple) and value and all(dataclasses.is_dataclass(v) for v in value):
            value = [to_dict(v, skip_defaults) for v in value]
        elif isinstance(value, tuple):
            value = list(value)
        out[f.name] = value
    return out


def _floats(value):
    """Integers given for floats hash as floats: every number is written as a float."""
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, dict):
        return {k: _floats(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_floats(v) for v in value]
    return value


def canonical_json(config) -> str:
    """Sorted-key, compact JSON of a config's non-default values: the text its hash is taken of.

    Leaving defaults out keeps every earlier hash (and stored dataset) valid when a new parameter is added off
    by default; a change of what a default means bumps :data:`SCHEMA_VERSION` instead.
    """
    return json.dumps({"type": type(config).__name__, "schema": SCHEMA_VERSION,
                       **_floats(to_dict(config, skip_defaults=True))}, sort_keys=True, separators=(",", ":"),
                      allow_nan=False)


def content_hash(config, length: int = 16) -> str:
    """Stable hex hash of a config's content (same content -> same hash, in any process or session)."""
    return hashlib.sha256(canonical_json(config).encode()).hexdigest()[:length]


def hash_of(data, length: int = 16) -> str:
    """Stable hex hash of any JSON-able value (sorted keys)."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:length]


# ------------------------------------------------------------------------------------------------------------
def parameter_paths(cls, prefix: str = "") -> list[str]:
    """Every dotted path of a leaf parameter of ``cls`` (for messages and documentation)."""
    paths = []
    hints = _hints(cls)
    for f in dataclasses.fields(cls):
        tp = _optional_inner(hints[f.name]) or hints[f.name]
        path = f"{prefix}{f.name}"
        item = _table_array_item(tp)
        if item is not None:
            paths.extend(parameter_paths(item, path + "[]."))
        else:
            paths.extend(parameter_paths(tp, path + ".") if _is_config(tp) else [path])
    return paths


def with_value(config, path: str, value, where: str = ""):
    """A copy of ``config`` with the leaf parameter at dotted ``path`` set to ``value`` (checked by its type).

    Raises :class:`ConfigError` naming ``where`` and the path when no such parameter exists or the value does
    not fit it.
    """
    name, _, rest = path.partition(".")
    fields = {f.name: f for f in dataclasses.fields(config)}
    label = f"{where}: " if where else ""
    if name not in fields:
        close = [p for p in parameter_paths(type(config)) if p.split(".")[-1] == path.split(".")[-1]]
        hint = f" (did you mean {', '.join(close[:3])}?)" if close else ""
        raise ConfigError(f"{label}{path}: no such parameter in {type(config).__name__}{hint}")
    hints = _hints(type(config))
    tp = hints[name]
    current = getattr(config, name)
    if rest:
        inner = _optional_inner(tp) or tp
        if not _is_config(inner):
            raise ConfigError(f"{label}{path}: {name} is a value, not a table of parameters")
        if current is None:
            current = inner()
        try:
            new = with_value(current, rest, value)
        except ConfigError as err:
            raise ConfigError(f"{label}{name}.{str(err)}") from None
    else:
        if _is_config(_optional_inner(tp) or tp) and not isinstance(value, dict):
            raise ConfigError(f"{label}{path}: is a table of parameters ({', '.join(parameter_paths(_optional_inner(tp) or tp)[:6])}"
                              "...), not a value")
        try:
            new = coerce_value(value, tp, name, fields[name].metadata)
        except ConfigError as err:
            raise ConfigError(f"{label}{path}: {str(err).split(': ', 1)[1]}") from None
    try:
        return dataclasses.replace(config, **{name: new})
    except (ValueError, TypeError) as err:
        raise ConfigError(f"{label}{path}: {err}") from None


def get_value(config, path: str):
    """The value of the leaf parameter at dotted ``path``."""
    for name in path.split("."):
        config = getattr(config, name)
    return config


# ------------------------------------------------------------------------------------------------------------
def read_mapping(path: str | Path) -> dict:
    """A TOML (``.toml``) or JSON (``.json``) file as a mapping; a syntax error names the file and line."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise ConfigError(f"{path}: config files are .toml or .json, got {path.suffix or 'no suffix'!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{path}: cannot be read ({err})") from None
    try:
        data = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML ({err})") from None
    except json.JSONDecodeError as err:
        raise ConfigError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a table of keys at the top level")
    return data


def load_config(cls, path: str | Path, section: str | None = None):
    """Load config ``cls`` from a TOML/JSON file (or one ``section`` of it); errors name the file and key."""
    data = read_mapping(path)
    if section is not None:
        data = data.get(section, {})
    try:
        return from_dict(cls, data, section or "")
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        text = repr(value)
        return text if ("." in text or "e" in text or "inf" in text or "nan" in text) else text + ".0"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)      # a JSON string is a valid TOML basic string
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _toml_key(key: str) -> str:
    return key if key.replace("_", "").replace("-", "").isalnum() else json.dumps(key)


def dumps_toml(data: dict, table: str = "") -> str:
    """TOML text of a mapping of scalars, lists, inline tables and nested tables (written as [sections])."""
    lines, tables = [], []
    for key, value in data.items():
        if isinstance(value, dict):
            tables.append((key, value))
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            tables.append((key, value))
        else:
            lines.append(f"{_toml_key(key)} = {_toml_value(value)}")
    for key, value in tables:
        name = f"{table}.{_toml_key(key)}" if table else _toml_key(key)
        if isinstance(value, list):
            for item in value:
                lines += ["", f"[[{name}]]", dumps_toml(item, name).strip("\n")]
        else:
            body = dumps_toml(value, name).strip("\n")
            lines += ["", f"[{name}]"] + ([body] if body else [])
    return "\n".join(lines).lstrip("\n") + "\n"


def save_config(config, path: str | Path, section: str | None = None) -> Path:
    """Write a config as TOML (``.toml``) or JSON (``.json``), atomically."""
    path = Path(path)
    data = to_dict(config)
    if section is not None:
        data = {section: data}
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return atomic_write_text(path, dumps_toml(data))
    if suffix == ".json":
        return atomic_write_text(path, json.dumps(data, indent=1) + "\n")
    raise ConfigError(f"{path}: config files are .toml or .json, got {path.suffix or 'no suffix'!r}")
