"""The one atomic writer (labio.atomic): whole or not at all, and with the permissions any other program's file
would get (mkstemp's 0600 would leave shared results unreadable by the group)."""
import os
import stat

import pytest

from labio.atomic import atomic_write_bytes, atomic_write_text, atomic_writer


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_a_new_file_gets_0666_minus_the_umask_as_open_would_give(tmp_path):
    """Compared with a file created by plain ``open`` in the same folder under the same umask."""
    old = os.umask(0o027)
    try:
        import importlib

        import labio.atomic
        importlib.reload(labio.atomic)                       # the writer reads the umask once, at import
        labio.atomic.atomic_write_text(tmp_path / "a.txt", "x")
        with open(tmp_path / "plain.txt", "w") as f:
            f.write("x")
        assert _mode(tmp_path / "a.txt") == _mode(tmp_path / "plain.txt") == 0o640
    finally:
        os.umask(old)
        importlib.reload(labio.atomic)


def test_a_replaced_file_keeps_its_permissions(tmp_path):
    path = tmp_path / "kept.txt"
    path.write_text("old")
    os.chmod(path, 0o604)
    atomic_write_bytes(path, b"new")
    assert path.read_bytes() == b"new" and _mode(path) == 0o604


def test_an_error_while_writing_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "report.md"
    atomic_write_text(path, "old")
    with pytest.raises(RuntimeError, match="content failed"):
        with atomic_writer(path) as handle:
            handle.write("half")
            raise RuntimeError("content failed")
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]
