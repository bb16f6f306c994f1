"""LLVM location and variant choice: never let Dr.Jit abort inside an unusable LLVM."""
import os
import subprocess
import sys

import pytest

from scenes.optics import backend


def test_a_usable_libllvm_is_found():
    path = backend.find_libllvm()
    assert path is not None and os.path.isfile(path)
    assert backend._llvm_major(path) >= 19


def test_variant_is_mono():
    assert backend.VARIANT in ("llvm_ad_mono", "cuda_ad_mono")
    assert backend.mi.variant() == backend.VARIANT


def test_missing_llvm_gives_clear_message(monkeypatch):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(backend, "find_libllvm", lambda: None)
    with pytest.raises(backend.BackendError, match="apt-get install libllvm19"):
        backend._configure_llvm()


def test_old_llvm_is_refused(monkeypatch, tmp_path):
    fake = tmp_path / "libLLVM-15.so.1"
    fake.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fake))
    with pytest.raises(backend.BackendError, match="LLVM 15"):
        backend._configure_llvm()


def test_bad_variant_override(monkeypatch):
    monkeypatch.setenv("WORKBENCH_VARIANT", "scalar_rgb")
    with pytest.raises(backend.BackendError, match="WORKBENCH_VARIANT"):
        backend.choose_variant()


def test_cli_reports_bad_llvm_without_aborting(tmp_path):
    """A process pointed at LLVM 15 exits with a message (exit 2), not SIGABRT inside LLVM."""
    fake = tmp_path / "libLLVM-15.so"
    fake.write_bytes(b"")
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(fake))
    proc = subprocess.run([sys.executable, "-m", "workbench.cli", "render", "checkerboard", "--views", "1",
                           "--scale", "0.1", "--out", str(tmp_path / "out")], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert "LLVM 15" in proc.stderr and "libllvm19" in proc.stderr
