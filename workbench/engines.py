"""Run any 2-D DIC engine on a dataset: a command line (as the DIC Challenge scripts do) or a Python function.

* **Command template**: ``'mytool {ref} {def} --subset {subset} --out {out}'`` — run without a shell (the
  template is split like a POSIX shell would, then each placeholder is replaced), once per deformed state.
  Placeholders: ``{ref}``, ``{def}`` (image files), ``{out}`` (the result file it must write), ``{subset}``,
  ``{step}`` (px), ``{roi}`` (``x0,y0,x1,y1``, inclusive pixel bounds of subset centres), ``{x0} {y0} {x1} {y1}``,
  and the instrument settings ``{order}`` (shape function: 1 affine, 2 quadratic), ``{interpolation}``
  (``biquintic`` or ``bicubic``), ``{prefilter_sigma}`` (Gaussian pre-filter, px).
* **Python entry point**: ``'package.module:function'``, called as
  ``function(ref, def, out, subset_px=.., step_px=.., roi_xyxy_px=(..), **options)`` and writing ``out``;
  the module may say which reader reads it (``RESULT_FORMAT = "pyvale"``) and which values of a setting it
  can take (``SUPPORTED_SETTINGS = {"interpolation": ("bicubic",)}``).

Settings that a caller judges (a gate's shape-function order and interpolant, :func:`check_settings`) must
reach the engine: a template needs their placeholders, a function their keywords (or ``**kwargs``); an engine
that cannot take one is refused before anything runs, naming the setting.

The engine sees image files only (as with a real rig); the result is read by :mod:`workbench.results` and
scored by :mod:`workbench.scoring.metrics`. An engine that fails, or writes no result file, is an error naming the
state and the command.
"""
from __future__ import annotations

import importlib
import inspect
import re
import shlex
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Instrument settings an engine can be given: keyword of a Python engine -> placeholder of a command template.
SETTINGS = {"order": "order", "interpolation": "interpolation", "prefilter_sigma_px": "prefilter_sigma"}
PLACEHOLDERS = ("ref", "def", "out", "subset", "step", "roi", "x0", "y0", "x1", "y1", *SETTINGS.values())
_PY_ENTRY = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


@dataclass(frozen=True)
class Engine:
    """A DIC engine: ``kind`` is ``"command"`` or ``"python"``; ``spec`` the template or ``module:function``."""

    kind: str
    spec: str

    @property
    def result_format(self) -> str | None:
        """The reader its module names (``RESULT_FORMAT``), for a Python engine; else None."""
        if self.kind != "python":
            return None
        return getattr(importlib.import_module(self.spec.split(":")[0]), "RESULT_FORMAT", None)


def parse_engine(text: str) -> Engine:
    """``module:function`` -> a Python engine; anything with a space or a placeholder -> a command template."""
    text = text.strip()
    if _PY_ENTRY.match(text):
        return Engine("python", text)
    try:
        words = shlex.split(text)
    except ValueError as err:
        raise ValueError(f"--engine {text!r}: {err}") from None
    if not words:
        raise ValueError("--engine is empty")
    found = set(re.findall(r"\{(\w+)\}", text))
    unknown = found - set(PLACEHOLDERS)
    if unknown:
        raise ValueError(f"--engine {text!r}: unknown placeholder(s) {', '.join('{' + u + '}' for u in sorted(unknown))}; "
                         f"known: {', '.join('{' + p + '}' for p in PLACEHOLDERS)}")
    for need in ("ref", "def", "out"):
        if need not in found:
            raise ValueError(f"--engine {text!r}: the template needs {{{need}}}")
    return Engine("command", text)


def instrument_settings(order: int, interpolation: str, prefilter_sigma_px: float = 0.0) -> dict:
    """The settings an engine must honour for a 2-D measurement (``SETTINGS`` keys). No pre-filter is not a
    setting: every engine sees the raw images unless told otherwise."""
    out = {"order": int(order), "interpolation": str(interpolation)}
    if prefilter_sigma_px:
        out["prefilter_sigma_px"] = float(prefilter_sigma_px)
    return out


def check_settings(engine: Engine, settings: dict, who: str = "the gate") -> None:
    """Refuse (``ValueError`` naming the setting) an engine that cannot take one of ``settings``.

    A command template must hold the setting's placeholder; a Python function must take its keyword (or
    ``**kwargs``); a module's ``SUPPORTED_SETTINGS`` (``{setting: allowed values}``) must allow its value.
    """
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        raise ValueError(f"{who}: unknown engine setting(s) {', '.join(unknown)} (known: {', '.join(SETTINGS)})")
    if engine.kind == "command":
        found = set(re.findall(r"\{(\w+)\}", engine.spec))
        for name, value in settings.items():
            if SETTINGS[name] not in found:
                raise ValueError(f"--engine {engine.spec!r}: {who} measures with {name} = {value!r}, but the template "
                                 f"has no {{{SETTINGS[name]}}} placeholder to pass it; put it where the tool takes "
                                 f"that setting, or set the tool's own value in the instrument settings")
        return
    module_name, func_name = engine.spec.split(":")
    try:
        module = importlib.import_module(module_name)
        func = getattr(module, func_name)
    except (ImportError, AttributeError) as err:
        raise ValueError(f"--engine {engine.spec}: {err}") from None
    try:
        params = inspect.signature(func).parameters
    except (TypeError, ValueError):
        params = {}
    takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    supported = getattr(module, "SUPPORTED_SETTINGS", {}) or {}
    for name, value in settings.items():
        if name not in params and not takes_any:
            raise ValueError(f"--engine {engine.spec}: {who} measures with {name} = {value!r}, but {func_name}() takes "
                             f"no {name!r} keyword (nor **kwargs); add it, or set the engine's own value in the "
                             f"instrument settings")
        if name in supported and value not in tuple(supported[name]):
            allowed = ", ".join(repr(v) for v in supported[name]) or "no value: the engine does not take it"
            raise ValueError(f"--engine {engine.spec}: {who} measures with {name} = {value!r}, which the engine does "
                             f"not offer ({module_name}.SUPPORTED_SETTINGS allows {allowed})")


def run_engine(engine: Engine, ref: Path, deformed: Path, out: Path, *, subset_px: int, step_px: int,
               roi_xyxy_px: tuple[int, int, int, int], timeout_s: float | None = None, options: dict | None = None
               ) -> dict:
    """Run ``engine`` on one pair; returns ``{"seconds", "command"}``. Raises RuntimeError when it fails.

    ``options``: keywords of a Python engine; for a command template, the :data:`SETTINGS` among them fill
    their placeholders (a placeholder with no value is an error naming it)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.exists():
        out.unlink()
    start = time.perf_counter()
    if engine.kind == "python":
        module_name, func_name = engine.spec.split(":")
        try:
            func = getattr(importlib.import_module(module_name), func_name)
        except (ImportError, AttributeError) as err:
            raise ValueError(f"--engine {engine.spec}: {err}") from None
        func(str(ref), str(deformed), str(out), subset_px=subset_px, step_px=step_px, roi_xyxy_px=tuple(roi_xyxy_px),
             **(options or {}))
        command = engine.spec
    else:
        values = {"ref": str(ref), "def": str(deformed), "out": str(out), "subset": str(subset_px),
                  "step": str(step_px), "roi": ",".join(str(int(v)) for v in roi_xyxy_px),
                  **{k: str(int(v)) for k, v in zip(("x0", "y0", "x1", "y1"), roi_xyxy_px)},
                  **{SETTINGS[k]: f"{v:g}" if isinstance(v, float) else str(v)
                     for k, v in (options or {}).items() if k in SETTINGS}}
        missing = sorted(set(re.findall(r"\{(\w+)\}", engine.spec)) - set(values))
        if missing:
            raise ValueError(f"--engine {engine.spec!r}: no value for {', '.join('{' + m + '}' for m in missing)} "
                             "(give the setting, e.g. the instrument's shape-function order)")
        argv = [re.sub(r"\{(\w+)\}", lambda m: values[m.group(1)], w) for w in shlex.split(engine.spec)]
        command = shlex.join(argv)
        try:
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
        except FileNotFoundError:
            raise ValueError(f"--engine: no such program {argv[0]!r}") from None
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"engine timed out after {timeout_s} s: {command}") from None
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-5:]
            raise RuntimeError(f"engine exited with {proc.returncode}: {command}\n  " + "\n  ".join(tail))
    if not out.is_file():
        raise RuntimeError(f"engine wrote no result file {out}: {command}")
    return {"seconds": time.perf_counter() - start, "command": command}


def array_engine(engine, workdir: Path, options: dict | None = None):
    """An array engine ``(reference, deformed, subset_px, step_px) -> (x, y, u, v)`` that runs ``engine`` (any
    engine of this module) on float TIFFs of the two images in ``workdir``, as the Star measurement expects."""
    import io as _io

    import tifffile

    from labio.atomic import atomic_write_bytes
    from workbench.results import read_result

    counter = {"n": 0}

    def run(reference, deformed, subset_px: int, step_px: int):
        counter["n"] += 1
        files = []
        for name, image in (("ref", reference), ("def", deformed)):
            buffer = _io.BytesIO()
            tifffile.imwrite(buffer, np.ascontiguousarray(image, dtype=np.float32))
            path = workdir / f"star_{counter['n']:02d}_{name}.tif"
            atomic_write_bytes(path, buffer.getvalue())
            files.append(path)
        h, w = np.shape(reference)
        margin = subset_px // 2 + 8
        out = workdir / f"star_{counter['n']:02d}.csv"
        run_engine(engine, files[0], files[1], out, subset_px=subset_px, step_px=step_px,
                   roi_xyxy_px=(margin, margin, w - 1 - margin, h - 1 - margin), options=options)
        r = read_result(out, engine.result_format or "native")
        return r.x_px, r.y_px, r.u_px, r.v_px

    run.__name__ = engine.spec
    return run


def ours(ref: str, deformed: str, out: str, *, subset_px: int = 33, step_px: int = 8, roi_xyxy_px=None,
         order: int = 1, interpolation: str = "biquintic", prefilter_sigma_px: float = 0.0) -> Path:
    """This project's instrument as a Python engine (native CSV): the reference the interface is checked with.

    Every keyword is a setting it honours; any other is a TypeError (nothing is silently ignored)."""
    from measurement.dic import DICSettings, correlate
    from measurement.image_io import read_grey

    settings = DICSettings(subset_size=subset_px, step=step_px, order=order, interpolation=interpolation,
                           lowpass_sigma_px=float(prefilter_sigma_px))
    result = correlate(read_grey(ref).astype(float), read_grey(deformed).astype(float), settings,
                       roi=None if roi_xyxy_px is None else tuple(int(v) for v in roi_xyxy_px))
    return result.to_csv(out)


RESULT_FORMAT = "native"     # of :func:`ours`
