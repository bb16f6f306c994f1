"""The one render cache: rendered datasets stored under the hash of the scenario content that made them.

``<store>/<kind>-<hash>/`` holds a dataset's files, ``scenario.json`` (the content it is the hash of) and
``manifest.json`` (:mod:`workbench.manifest`). A dataset is rendered into a temporary folder
``<store>/.partial/<kind>-<hash>@<host>-<pid>/`` and renamed into place when complete, so a folder under its hash
is always complete and a killed render leaves only a partial folder that is never read (and is cleared by a
later run once its process is gone). Processes that need the same dataset at once take a lock file: one
renders, the others wait and reuse it.

Results of the instrument on a dataset (e.g. a calibration) are stored the same way inside the dataset
folder, under ``results/<hash>/`` (:meth:`DatasetStore.result`).
"""
from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import socket
import time
from pathlib import Path
from typing import Callable

from labio.atomic import atomic_write_text
from workbench.manifest import complete_manifest

PARTIAL = ".partial"
_HOST = socket.gethostname().replace("@", "_").replace("/", "_")
LOCKS = ".locks"
ENV_STORE = "WORKBENCH_STORE"


def default_store_dir() -> Path:
    """``$WORKBENCH_STORE``, else ``~/.cache/scheimpflug-dic-workbench/datasets``."""
    if os.environ.get(ENV_STORE):
        return Path(os.environ[ENV_STORE])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "scheimpflug-dic-workbench" / "datasets"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@contextlib.contextmanager
def _locked(path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)      # released when the handle closes, also when the process dies
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def stored_render(kind: str, content: dict, render: Callable[[Path], object],
                  store: "DatasetStore | str | Path | None" = None) -> tuple[Path, bool]:
    """The dataset of ``kind`` made from ``content`` (any JSON-able description of everything that changes its
    files), rendered by ``render(folder)`` unless the store holds it: the one render cache of every command."""
    from workbench.config import hash_of

    store = store if isinstance(store, DatasetStore) else DatasetStore(store)
    return store.ensure(kind, hash_of(content), content, render)


def dataset_record(kind: str, content: dict, folder: Path | None = None) -> dict:
    """How a report names the dataset it measured, portably: its kind, the hash of its content (the store
    folder ``<kind>-<hash>`` on any machine), the content itself (everything that made the images: rerunning the
    experiment with it renders the same images) and, when given, where this run found it."""
    from workbench.config import hash_of

    key = hash_of(content)
    out = {"kind": kind, "hash": key, "store_folder": f"{kind}-{key}", "content": content}
    if folder is not None:
        out["found_at"] = str(folder)
    return out


class DatasetStore:
    """Content-addressed datasets under ``root`` (see the module doc)."""

    def __init__(self, root: str | Path | None = None):
        self.root = Path(root) if root is not None else default_store_dir()

    def path(self, kind: str, key: str) -> Path:
        return self.root / f"{kind}-{key}"

    def find(self, kind: str, key: str) -> Path | None:
        """The complete dataset of ``kind`` under ``key``, or None."""
        folder = self.path(kind, key)
        return folder if complete_manifest(folder, kind) is not None else None

    def clear_partials(self) -> list[Path]:
        """Delete partial folders left by processes of this host that no longer run; returns what was deleted.

        Partial folders are named ``<kind>-<hash>@<host>-<pid>``: on a shared file system another host's
        worker may be rendering into its own, so only this host's dead processes are cleared.
        """
        removed = []
        partial = self.root / PARTIAL
        if not partial.is_dir():
            return removed
        for folder in partial.iterdir():
            host, _, pid = folder.name.rpartition("@")[2].rpartition("-")
            if host == _HOST and pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
        return removed

    def ensure(self, kind: str, key: str, content: dict, render: Callable[[Path], dict | None]) -> tuple[Path, bool]:
        """The dataset of ``kind`` under ``key``, rendered by ``render(folder)`` if it is not stored yet.

        ``render`` writes the dataset's files into the (empty, temporary) folder it is given and completes it
        with :func:`workbench.manifest.complete_folder` of ``kind``. Returns ``(folder, reused)``.
        """
        found = self.find(kind, key)
        if found is not None:
            return found, True
        with _locked(self.root / LOCKS / f"{kind}-{key}.lock"):
            found = self.find(kind, key)                 # another process may have rendered it meanwhile
            if found is not None:
                return found, True
            final = self.path(kind, key)
            tmp = self.root / PARTIAL / f"{kind}-{key}@{_HOST}-{os.getpid()}"
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir(parents=True)
            start = time.perf_counter()
            render(tmp)
            atomic_write_text(tmp / "scenario.json", json.dumps(
                {"kind": kind, "hash": key, "content": content,
                 "render_s": round(time.perf_counter() - start, 2)}, indent=1))
            if complete_manifest(tmp, kind) is None:
                raise RuntimeError(f"the {kind} render into {tmp} did not complete its manifest")
            if final.exists():                           # an incomplete folder under the hash: never valid
                shutil.rmtree(final)
            os.replace(tmp, final)
            return final, False

    def result(self, dataset: Path, key: str, compute: Callable[[Path], None], name: str) -> tuple[Path, bool]:
        """A result of the instrument on ``dataset``, stored as ``dataset/results/<key>/`` (computed once).

        ``compute(folder)`` writes the result's files, including ``name``, whose presence marks it complete.
        Returns ``(folder, reused)``.
        """
        final = dataset / "results" / key
        if (final / name).is_file():
            return final, True
        with _locked(self.root / LOCKS / f"result-{dataset.name}-{key}.lock"):
            if (final / name).is_file():
                return final, True
            tmp = dataset / "results" / f".partial-{key}-{os.getpid()}"
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir(parents=True)
            compute(tmp)
            if not (tmp / name).is_file():
                raise RuntimeError(f"the result computed into {tmp} has no {name}")
            if final.exists():
                shutil.rmtree(final)
            os.replace(tmp, final)
            return final, False
