"""The one way files are written: atomically (whole or not at all), with write errors checked.

Every command writes through these functions (DESIGN §8): the content goes to a temporary file in the target
folder, is flushed and fsync'ed, then renamed over the target (``os.replace`` is atomic on one filesystem).
A full disk, a killed process or an exception while producing the content leaves the old file (or no file),
never a truncated one, and the error names the file.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

#: The process's umask, read once: mkstemp creates 0600 files, but a written file should get the permissions any
#: other program's file gets (0666 minus the umask), or a replaced file keep its own.
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_writer(path: str | Path, mode: str = "w", *, newline: str | None = None,
                  encoding: str | None = "utf-8") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on a clean exit fsync it and rename it to ``path``.

    Parameters
    ----------
    path : target file; its folder is created if missing
    mode : "w" (text) or "wb" (binary)
    newline, encoding : as for :func:`open` (text mode only)

    Raises
    ------
    OSError
        Naming ``path`` when the folder cannot be created or the data cannot be written, flushed or renamed
        (e.g. ENOSPC); the temporary file is removed and ``path`` is untouched.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"mode must be 'w' or 'wb', got {mode!r}")
    text = mode == "w"
    with atomic_path(path) as tmp:      # fsync, rename, clean-up and the error naming ``path`` are its
        with open(tmp, mode, **({"newline": newline, "encoding": encoding} if text else {})) as handle:
            yield handle


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` for a library that writes files by name (netCDF, HDF5); on a clean exit
    it is fsync'ed and renamed to ``path``, on an error removed (``path`` untouched). Errors name ``path``."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        os.close(fd)
    except OSError as err:
        raise OSError(f"cannot write {path}: {err.strerror or err}") from None
    try:
        yield Path(tmp)
        os.chmod(tmp, _file_mode(path))
        with open(tmp, "rb+") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(err, OSError):
            raise OSError(f"cannot write {path}: {err.strerror or err}") from None
        raise


def _file_mode(path: Path) -> int:
    """The permissions ``path`` keeps (an existing file) or gets (a new one: 0666 minus the umask)."""
    try:
        return os.stat(path).st_mode & 0o7777
    except OSError:
        return 0o666 & ~_UMASK


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the path."""
    with atomic_writer(path, "w") as handle:
        handle.write(text)
    return Path(path)


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_writer(path, "wb") as handle:
        handle.write(data)
    return Path(path)


def atomic_write_image(path: str | Path, image) -> Path:
    """Encode an image with OpenCV by the file's extension (PNG, TIFF, ...) and write it atomically."""
    import cv2

    path = Path(path)
    ok, buffer = cv2.imencode(path.suffix or ".png", image)
    if not ok:
        raise OSError(f"cannot encode {path} as {path.suffix or '.png'}")
    return atomic_write_bytes(path, buffer.tobytes())
