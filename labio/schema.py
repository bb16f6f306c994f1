"""The one way input files are validated: a schema walk that names the file and the key of every defect.

Every loader of a structured file (calibration JSON, OpenCV YAML, ``truth.json``) reads the file into plain
Python values (dicts, lists, numbers, strings) and walks them with :class:`Node`, which knows the file and the
key path it came from. Every check (required key, type, finite number, physical range, array shape, rotation)
raises :class:`FileFormatError`, a :class:`ValueError` whose message starts ``<file>: key '<key>':``, so callers
that catch ``ValueError`` (the CLI prints one line and exits 2) need nothing else, and no malformed file ever
surfaces as a ``KeyError``, ``TypeError``, ``AttributeError`` or a silently substituted default.

Example::

    doc = read_json_file(path)                      # FileFormatError if empty, not UTF-8, not JSON
    fx = doc["left"]["intrinsics"]["fx"].number(0, 1e6, unit="px")
    R = doc["stereo"]["R_right_from_left"].rotation()
"""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Iterable

import numpy as np

#: Rotation matrices read from files must satisfy ``|R^T R - I| <= ROTATION_TOL`` (max abs) and ``det R > 0``.
ROTATION_TOL = 1e-6
#: Deeper nesting than this is refused (no real file of ours nests beyond 5).
MAX_DEPTH = 64


class FileFormatError(ValueError):
    """An input file that is missing, empty, unreadable as its format, or violates its schema.

    ``file`` and ``key`` (dotted path, ``""`` for the file as a whole) name where; ``problem`` says what.
    """

    def __init__(self, file, key: str, problem: str):
        self.file, self.key, self.problem = str(file), str(key), str(problem)
        where = f"{self.file}: key '{self.key}'" if self.key else self.file
        super().__init__(f"{where}: {self.problem}")

    def __reduce__(self):
        return type(self), (self.file, self.key, self.problem)


def _type_name(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"a boolean ({value})"
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + "..."
        return f"a string ({shown!r})"
    if isinstance(value, (int, float)):
        return f"a number ({value!r})" if not isinstance(value, int) or abs(value) < 10 ** 30 else "a huge integer"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)}"
    return type(value).__name__


def _fmt(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def _range_text(lo, hi, lo_open, hi_open, unit) -> str:
    u = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{_fmt(lo)}, {_fmt(hi)}{')' if hi_open else ']'}{u}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {_fmt(lo)}{u}"
    return f"{'<' if hi_open else '<='} {_fmt(hi)}{u}"


class Node:
    """A value read from ``file`` at ``key``, with checked accessors; every failure is a FileFormatError."""

    __slots__ = ("value", "file", "key")

    def __init__(self, value: Any, file, key: str = ""):
        self.value, self.file, self.key = value, str(file), key

    def error(self, problem: str, key: str | None = None) -> FileFormatError:
        return FileFormatError(self.file, self.key if key is None else key, problem)

    def _child(self, name) -> str:
        if isinstance(name, int):
            return f"{self.key}[{name}]"
        return f"{self.key}.{name}" if self.key else str(name)

    # --- structure --------------------------------------------------------------------------------------
    def mapping(self) -> dict:
        if not isinstance(self.value, dict):
            what = "the file's top level" if not self.key else "it"
            raise self.error(f"{what} must be a mapping (JSON object / YAML map), got {_type_name(self.value)}")
        return self.value

    def __contains__(self, name: str) -> bool:
        return name in self.mapping()

    def __getitem__(self, name: str) -> "Node":
        d = self.mapping()
        if name not in d:
            raise self.error("required key is missing", key=self._child(name))
        return Node(d[name], self.file, self._child(name))

    def get(self, name: str) -> "Node | None":
        """The child ``name``, or None when absent (for optional keys only)."""
        d = self.mapping()
        return Node(d[name], self.file, self._child(name)) if name in d else None

    def keys(self) -> list[str]:
        return list(self.mapping())

    def only_keys(self, allowed: Iterable[str]) -> None:
        """Refuse keys outside ``allowed`` (typos would otherwise be ignored silently)."""
        allowed = set(allowed)
        extra = sorted(str(k) for k in self.mapping() if k not in allowed)
        if extra:
            raise self.error(f"unknown key(s) {', '.join(map(repr, extra))}; allowed: {', '.join(sorted(allowed))}")

    def sequence(self, min_len: int = 0, max_len: int | None = None) -> list["Node"]:
        if not isinstance(self.value, (list, tuple)):
            raise self.error(f"must be a list, got {_type_name(self.value)}")
        n = len(self.value)
        if n < min_len or (max_len is not None and n > max_len):
            want = f"{min_len}" if max_len == min_len else (f"{min_len} to {max_len}" if max_len is not None
                                                             else f"at least {min_len}")
            raise self.error(f"must be a list of {want} entries, got {n}")
        return [Node(v, self.file, self._child(i)) for i, v in enumerate(self.value)]

    # --- scalars ----------------------------------------------------------------------------------------
    def number(self, lo: float | None = None, hi: float | None = None, *, lo_open: bool = True,
               hi_open: bool = True, unit: str = "") -> float:
        """A finite real number (not a boolean, not a string), optionally in a range."""
        v = self.value
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(f"must be a number, got {_type_name(v)}")
        try:
            x = float(v)
        except OverflowError:
            raise self.error("must be a finite number, got an integer beyond the floating-point range") from None
        if not math.isfinite(x):
            raise self.error(f"must be a finite number, got {x}")
        if ((lo is not None and (x <= lo if lo_open else x < lo))
                or (hi is not None and (x >= hi if hi_open else x > hi))):
            raise self.error(f"must be {_range_text(lo, hi, lo_open, hi_open, unit)}, got {x:.17g}")
        return x

    def integer(self, lo: int | None = None, hi: int | None = None) -> int:
        """An integer (a float with an integral value is accepted), optionally in ``[lo, hi]``."""
        v = self.value
        if isinstance(v, float) and math.isfinite(v) and v == int(v):
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(f"must be an integer, got {_type_name(v)}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            shown = str(v) if abs(v) < 10 ** 30 else "a huge integer"
            raise self.error(f"must be an integer {_range_text(lo, hi, False, False, '')}, got {shown}")
        return v

    def string(self, choices: Iterable[str] | None = None, *, nonempty: bool = True) -> str:
        v = self.value
        if not isinstance(v, str):
            raise self.error(f"must be a string, got {_type_name(v)}")
        if choices is not None:
            choices = tuple(choices)
            if v not in choices:
                raise self.error(f"must be one of {', '.join(map(repr, choices))}, got {_type_name(v)}")
        elif nonempty and not v:
            raise self.error("must be a non-empty string")
        return v

    # --- arrays -----------------------------------------------------------------------------------------
    def array(self, shape: tuple[int, ...], *, bound: float = 1e12) -> np.ndarray:
        """Nested lists of finite numbers of exactly ``shape`` (``|x| < bound``), as a float64 array."""
        out = np.empty(shape, float)
        self._fill(out, (), shape, bound)
        return out

    def _fill(self, out, index, shape, bound):
        if len(index) == len(shape):
            out[index] = self.number(-bound, bound)
            return
        for i, child in enumerate(self.sequence(shape[len(index)], shape[len(index)])):
            child._fill(out, index + (i,), shape, bound)

    def vector(self, n: int = 3, *, lo_norm: float | None = None, hi_norm: float | None = None,
               unit: str = "") -> np.ndarray:
        """An n-vector of finite numbers whose norm is in ``(lo_norm, hi_norm)`` when given."""
        v = self.array((n,))
        norm = float(np.linalg.norm(v))
        if (lo_norm is not None and not norm > lo_norm) or (hi_norm is not None and not norm < hi_norm):
            raise self.error(f"its length must be {_range_text(lo_norm, hi_norm, True, True, unit)}, got {norm:.6g}")
        return v

    def rotation(self, tol: float = ROTATION_TOL) -> np.ndarray:
        """A proper 3x3 rotation: orthonormal within ``tol`` (max abs of R^T R - I) and det R > 0."""
        R = self.array((3, 3), bound=1e6)
        err = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if not err <= tol:
            raise self.error(f"must be a rotation matrix (R^T R = I within {tol:g}), deviates by {err:.3g}")
        if not np.linalg.det(R) > 0:
            raise self.error("must be a proper rotation (det R = +1), got a reflection (det R = -1)")
        return R

    # --- dataclasses ------------------------------------------------------------------------------------
    def dataclass(self, cls, *, ranges: dict[str, tuple] | None = None, ignore: Iterable[str] = (),
                  number_bound: float = 1e9, int_range: tuple[int, int] = (0, 2 ** 63 - 1),
                  optional: Iterable[str] = ()):
        """Build ``cls`` (a dataclass of float/int/str fields) from a mapping holding every field.

        Every field is required (a missing one is never filled with its default) except those named in
        ``optional`` (fields added after files were written: absent means the default), unknown keys are refused
        (``ignore`` lists keys to skip, e.g. a ``type`` tag), floats are finite with ``|x| < number_bound`` or in
        ``ranges[name] = (lo, hi)`` (open bounds; ``(lo, hi, lo_open, hi_open)`` to choose), ints in
        ``ranges[name]`` or ``int_range`` (closed); a ValueError from the class' own checks is re-raised naming
        the file and this key.
        """
        ranges = ranges or {}
        ignore = set(ignore)
        flds = [f for f in dataclasses.fields(cls) if f.init]
        self.only_keys({f.name for f in flds} | ignore)
        optional = set(optional)
        kwargs = {}
        for f in flds:
            if f.name in optional and self.get(f.name) is None:
                continue
            child = self[f.name]
            kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
            if kind == "float":
                lo, hi, lo_open, hi_open = (tuple(ranges.get(f.name, (-number_bound, number_bound)))
                                            + (True, True))[:4]
                kwargs[f.name] = child.number(lo, hi, lo_open=lo_open, hi_open=hi_open)
            elif kind == "int":
                lo, hi = ranges.get(f.name, int_range)
                kwargs[f.name] = child.integer(lo, hi)
            elif kind == "str":
                kwargs[f.name] = child.string(nonempty=False)
            else:                                                    # pragma: no cover - programming error
                raise TypeError(f"{cls.__name__}.{f.name}: unsupported field type {f.type!r}")
        try:
            return cls(**kwargs)
        except ValueError as err:
            raise self.error(f"invalid {cls.__name__}: {err}") from None


# --------------------------------------------------------------------------------------------------------
def read_file_bytes(path: str | Path, what: str = "file", *, max_bytes: int | None = None) -> bytes:
    """The bytes of a text file ``path``; FileFormatError if it is missing, a folder, empty, binary (NUL bytes)
    or larger than ``max_bytes``."""
    path = Path(path)
    if not path.exists():
        raise FileFormatError(path, "", f"{what} does not exist")
    if not path.is_file():
        raise FileFormatError(path, "", f"{what} is not a regular file")
    if max_bytes is not None and path.stat().st_size > max_bytes:
        raise FileFormatError(path, "", f"{what} is {path.stat().st_size} bytes, more than the {max_bytes} a file of "
                                        f"this kind can sensibly hold")
    data = path.read_bytes()
    if not data.strip():
        raise FileFormatError(path, "", f"{what} is empty")
    if b"\x00" in data:
        raise FileFormatError(path, "", f"{what} contains NUL bytes: it is not a text file")
    return data


def read_text_file(path: str | Path, what: str = "file", *, max_bytes: int | None = None) -> str:
    """The UTF-8 text of ``path``; FileFormatError if it is missing, a folder, empty, binary, not UTF-8 or
    larger than ``max_bytes``."""
    data = read_file_bytes(path, what, max_bytes=max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise FileFormatError(path, "", f"{what} is not UTF-8 text (byte {err.start})") from None


def read_json_file(path: str | Path, what: str = "file") -> Node:
    """Parse ``path`` as JSON into a :class:`Node`; every failure is a FileFormatError naming the file."""
    text = read_text_file(path, what)
    try:
        value = json.loads(text)
    except json.JSONDecodeError as err:
        raise FileFormatError(path, "", f"is not valid JSON: {err}") from None
    except RecursionError:
        raise FileFormatError(path, "", "is not a usable JSON file: nested too deeply") from None
    except ValueError as err:                   # e.g. an integer literal beyond Python's digit limit
        raise FileFormatError(path, "", f"is not a usable JSON file: {err}") from None
    return Node(value, path)
