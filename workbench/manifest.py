"""Dataset folders: a manifest of the files a dataset owns, written last, and the rules for reusing a folder.

A command that writes a dataset (rendered views + ``truth.json``, stereo results) into a folder:

1. :func:`prepare_folder` first: a folder holding an earlier dataset (a ``manifest.json``, an interrupted
   write, or an older ``truth.json`` without a manifest) or files the new dataset would replace is refused
   unless ``overwrite``; with it, exactly the files the earlier dataset owns are deleted (its manifest first),
   nothing else. A hidden ``.workbench-pending.json`` then lists every file the write may leave behind, so an
   interrupted write is recognised (and can be cleared) later.
2. writes its files (each one atomically, :mod:`labio.atomic`), ``truth.json`` last;
3. :func:`complete_folder`: ``manifest.json`` (the files, the settings) is written last and the pending marker
   removed. A folder whose manifest exists is complete; :func:`complete_manifest` says whether a folder holds a
   complete dataset whose files are all present (reuse of renders relies on it).
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from labio.atomic import atomic_write_text, atomic_writer

MANIFEST_NAME = "manifest.json"
PENDING_NAME = ".workbench-pending.json"
FORMAT = "workbench-dataset-manifest/1"
_RESERVED = (MANIFEST_NAME, PENDING_NAME)


class DatasetFolderError(ValueError):
    """An output folder cannot take a new dataset (an earlier one is there, or its manifest is unreadable)."""


def _plain_names(names, where: Path) -> list[str]:
    """File names inside the folder itself (no paths): a manifest never makes anyone delete outside it."""
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise DatasetFolderError(f"{where}: 'files' must be a list of file names")
    bad = [n for n in names if not n or n in (".", "..") or Path(n).name != n or "/" in n or "\\" in n]
    if bad:
        raise DatasetFolderError(f"{where}: file names must be plain names inside the folder, got {bad[:3]}")
    return [n for n in names if n not in _RESERVED]


def _read_json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DatasetFolderError(f"{path} cannot be read as a dataset manifest ({err}); remove it by hand if the "
                                 "folder holds no dataset") from None
    if not isinstance(data, dict):
        raise DatasetFolderError(f"{path} is not a dataset manifest (expected a JSON object)")
    return data


def read_manifest(folder: str | Path) -> dict | None:
    """The folder's ``manifest.json`` (checked: format, kind, plain file names), or None if it has none."""
    path = Path(folder) / MANIFEST_NAME
    if not path.is_file():
        return None
    data = _read_json(path)
    if data.get("format") != FORMAT:
        raise DatasetFolderError(f"{path}: unknown format {data.get('format')!r}, expected {FORMAT!r}")
    if not isinstance(data.get("kind"), str):
        raise DatasetFolderError(f"{path}: 'kind' must be a string")
    data["files"] = _plain_names(data.get("files"), path)
    return data


def _legacy_files(truth_path: Path) -> list[str]:
    """Files an older dataset (``truth.json`` without a manifest) lists: its images and the truth itself."""
    names = []
    try:
        truth = json.loads(truth_path.read_text(encoding="utf-8"))
        for image in truth.get("images", []) if isinstance(truth, dict) else []:
            if isinstance(image, dict) and isinstance(image.get("file"), str):
                names.append(image["file"])
        for state in truth.get("states", []) if isinstance(truth, dict) else []:
            files = state.get("files") if isinstance(state, dict) else None
            if isinstance(files, dict):
                names.extend(v for v in files.values() if isinstance(v, str))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        pass
    names = [n for n in names if n and Path(n).name == n and n not in _RESERVED and n not in (".", "..")]
    return sorted(set(names)) + [truth_path.name]


def earlier_dataset(folder: str | Path) -> tuple[str, list[str]] | None:
    """What an earlier dataset in ``folder`` owns: ``(state, file names)`` with state ``"complete"`` (a
    manifest), ``"incomplete"`` (an interrupted write: pending marker, no manifest) or ``"legacy"`` (a
    ``truth.json`` without a manifest); None when the folder holds none."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    if manifest is not None:
        return "complete", manifest["files"]
    pending = folder / PENDING_NAME
    if pending.is_file():
        return "incomplete", _plain_names(_read_json(pending).get("files"), pending)
    if (folder / "truth.json").is_file():
        return "legacy", _legacy_files(folder / "truth.json")
    return None


def _listing(names: list[str], limit: int = 3) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def prepare_folder(folder: str | Path, kind: str, planned_files, *, overwrite: bool,
                   option: str = "--overwrite", dry_run: bool = False) -> Path:
    """Make ``folder`` ready to receive a new dataset of ``kind`` that writes ``planned_files``.

    ``dry_run``: only check (raise as below) and change nothing, so a command can refuse a folder before its
    long work and prepare it just before its first write.

    Raises
    ------
    DatasetFolderError
        ``folder`` is a file; or it holds an earlier dataset, or files the new one would replace, and
        ``overwrite`` is False (the message names the folder, what it holds and ``option``).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise DatasetFolderError(f"output folder {folder} is a file, not a folder")
    planned = _plain_names(list(planned_files), folder)
    earlier = earlier_dataset(folder) if folder.is_dir() else None
    owned = earlier[1] if earlier else []
    present = [n for n in owned if (folder / n).exists()]
    clashes = [n for n in planned if n not in owned and (folder / n).exists()]
    if (earlier or clashes) and not overwrite:
        if earlier:
            state, _ = earlier
            what = {"complete": f"an earlier dataset ({MANIFEST_NAME} lists {len(owned)} files)",
                    "incomplete": f"an incomplete dataset (an interrupted write left {len(present)} of its files)",
                    "legacy": f"an earlier dataset (truth.json without {MANIFEST_NAME}, {len(present)} files)"}[state]
            raise DatasetFolderError(f"{folder} holds {what}: pass {option} to replace it (deletes exactly the "
                                     "files the earlier dataset owns) or choose another folder")
        raise DatasetFolderError(f"{folder} holds files this {kind} dataset would replace ({_listing(clashes)}) but "
                                 f"no dataset manifest: pass {option} to replace them or choose another folder")
    if dry_run:
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    # From here on an interruption leaves a marker that owns everything this write may leave behind.
    atomic_write_text(folder / PENDING_NAME, json.dumps({"kind": kind, "files": sorted(set(owned) | set(planned))},
                                                        indent=1))
    if earlier:
        with contextlib.suppress(FileNotFoundError):
            (folder / MANIFEST_NAME).unlink()           # first: a manifest never lists deleted files
        for name in owned:
            path = folder / name
            if path.is_file() or path.is_symlink():
                try:
                    path.unlink()
                except OSError as err:
                    raise DatasetFolderError(f"cannot delete {path} of the earlier dataset: {err.strerror or err}") \
                        from None
    return folder


def complete_folder(folder: str | Path, kind: str, files, settings: dict | None = None) -> Path:
    """Write ``manifest.json`` (the dataset's files and settings) last, then drop the pending marker."""
    folder = Path(folder)
    names = _plain_names(list(files), folder)
    missing = [n for n in names if not (folder / n).is_file()]
    if missing:
        raise DatasetFolderError(f"{folder}: the dataset's files {_listing(missing)} were not written")
    manifest = {"format": FORMAT, "kind": kind, "complete": True, "files": names, "settings": settings or {},
                "about": "The files this dataset owns, written after all of them: its presence means the dataset is "
                         "complete. `--overwrite` deletes exactly these files (and this manifest)."}
    path = atomic_write_text(folder / MANIFEST_NAME, json.dumps(manifest, indent=1))
    with contextlib.suppress(FileNotFoundError):
        (folder / PENDING_NAME).unlink()
    return path


def complete_manifest(folder: str | Path, kind: str | None = None) -> dict | None:
    """The manifest of a complete dataset in ``folder`` whose files are all present (of ``kind``), else None.

    An unreadable manifest counts as no dataset here (the caller re-renders); :func:`prepare_folder` refuses it.
    """
    try:
        manifest = read_manifest(folder)
    except DatasetFolderError:
        return None
    if manifest is None or (kind is not None and manifest["kind"] != kind) or manifest.get("complete") is not True:
        return None
    if not all((Path(folder) / name).is_file() for name in manifest["files"]):
        return None
    return manifest


class _Failed(Exception):
    """Carries a write error out through the atomic writers (which would otherwise re-word an OSError)."""


def write_texts_together(texts: dict) -> list[Path]:
    """Write several text files so that either all of them are replaced or none is.

    Every file is written to its temporary file and fsync'ed (this is where a full disk fails) before the first
    one is renamed into place; an error names the file and leaves every target untouched.
    """
    paths = [Path(p) for p in texts]
    try:
        with contextlib.ExitStack() as stack:
            handles = []
            for path in paths:
                try:
                    handles.append(stack.enter_context(atomic_writer(path, "w")))
                except OSError as err:          # already names the file
                    raise _Failed(str(err)) from None
            for path, handle, text in zip(paths, handles, texts.values()):
                try:
                    handle.write(text)
                    handle.flush()
                    os.fsync(handle.fileno())
                except OSError as err:
                    raise _Failed(f"cannot write {path}: {err.strerror or err}") from None
    except _Failed as failed:
        raise OSError(str(failed)) from None
    return paths


def save_figure(fig, path: str | Path, **savefig_kwargs) -> Path:
    """``fig.savefig`` through the atomic writer: rendered to memory, then written whole (format from the suffix)."""
    import io

    from labio.atomic import atomic_write_bytes

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower() or "png"
    if fmt == "png":                    # a report's figure: with the record of its axes (labio.figures)
        from labio.figures import png_bytes

        dpi = savefig_kwargs.pop("dpi", 110)
        return atomic_write_bytes(path, png_bytes(fig, dpi=dpi, close=False, **savefig_kwargs))
    buffer = io.BytesIO()
    fig.savefig(buffer, format=fmt, **savefig_kwargs)
    return atomic_write_bytes(path, buffer.getvalue())
