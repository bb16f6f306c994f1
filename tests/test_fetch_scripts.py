"""The test-data fetch scripts (``scripts/fetch_twin_data.sh``, ``scripts/fetch_multidic.sh``) stop on any file
they could not fetch, naming it, and take their files from a local mirror when there is no network.

No test touches the network: the download path runs against a folder (``--base-url``, a ``file://`` URL or a
plain path) or against a stand-in ``curl`` on ``PATH`` that fails like ``curl -f`` on one missing file.
"""
from __future__ import annotations

import os
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = {"twin": ROOT / "scripts" / "fetch_twin_data.sh", "multidic": ROOT / "scripts" / "fetch_multidic.sh"}
#: The file each test removes from its mirror (one with a space in its name, which the URL must escape).
MISSING = {"twin": "tests/regression/dic_challenge_5_znssd/images/Sample5 Reference.tif",
           "multidic": "sample_data/Sample data instructions.pdf"}
#: The success line each script prints last (and only after every file is in place).
DONE = {"twin": re.compile(r"\[fetch_twin_data\] \d+ files in "),
        "multidic": re.compile(r"\[fetch_multidic\] \d+ files in ")}

pytestmark = pytest.mark.skipif(shutil.which("bash") is None or shutil.which("curl") is None,
                                reason="needs bash and curl")


def _repository_paths(name: str) -> list[str]:
    """Every repository path the script fetches on the download path (its ``--list`` of files)."""
    proc = subprocess.run(["bash", str(SCRIPTS[name]), "--list"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    paths = proc.stdout.splitlines()
    assert MISSING[name] in paths and len(paths) > 10
    return paths


def _mirror(tmp_path: Path, name: str, missing: str | None = None) -> Path:
    """A folder laid out like the repository, each file holding its own path (tiny, distinct contents)."""
    root = tmp_path / "mirror"
    for rel in _repository_paths(name):
        if rel == missing:
            continue
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(f"fake {rel}\n")
    return root


def _run(name: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPTS[name]), *args], capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_a_download_that_fails_stops_the_script_naming_the_file(tmp_path, name):
    """curl failing on one file (as ``curl -f`` does on an HTTP 404) must stop the script: before the fix the
    failure on the left of ``curl ... && mv`` did not trip ``set -e``, and the script went on to report every
    file fetched. A stand-in curl on PATH answers every URL with a tiny file but that one, so no network is
    touched."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake = bin_dir / "curl"
    # "-o FILE" is the destination, the other argument that is no option the URL; the file MISSING[name] fails as
    # curl -f does on a 404 (exit 22), every other one gets a tiny stand-in content
    fake.write_text("#!/usr/bin/env bash\n"
                    "out=''; url=''\n"
                    "while [ $# -gt 0 ]; do case \"$1\" in\n"
                    "    -o) out=\"$2\"; shift 2;; -*) shift;; *) url=\"$1\"; shift;;\n"
                    "esac; done\n"
                    "rel=\"${url#https://raw.githubusercontent.com/*/*/*/}\"; rel=\"${rel//%20/ }\"\n"
                    f"if [ \"$rel\" = '{MISSING[name]}' ]; then\n"
                    "    echo 'curl: (22) The requested URL returned error: 404' >&2; exit 22\n"
                    "fi\n"
                    "echo \"fake $rel\" > \"$out\"\n")
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    dest = tmp_path / "dest"
    proc = _run(name, "--dest", str(dest), env={"PATH": f"{bin_dir}:{os.environ['PATH']}"})
    assert proc.returncode != 0, proc.stdout
    assert MISSING[name] in proc.stderr
    assert not DONE[name].search(proc.stdout)
    assert not (dest / "SOURCE.txt").exists()
    assert not list(dest.rglob("*.part"))


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_a_local_mirror_that_lacks_a_file_stops_the_script_naming_the_file(tmp_path, name):
    mirror = _mirror(tmp_path, name, missing=MISSING[name])
    dest = tmp_path / "dest"
    proc = _run(name, "--base-url", mirror.as_uri(), "--dest", str(dest))
    assert proc.returncode != 0, proc.stdout
    assert MISSING[name] in proc.stderr and "could not fetch" in proc.stderr
    assert not DONE[name].search(proc.stdout)
    assert not (dest / "SOURCE.txt").exists()
    assert not list(dest.rglob("*.part"))
    missing_out = MISSING[name].rsplit("/", 1)[-1]
    assert not list(dest.rglob(missing_out))


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_a_complete_local_mirror_gives_every_file_without_a_network(tmp_path, name):
    """The mirror as a plain folder path through the environment variable, as file:// URL through the option."""
    mirror = _mirror(tmp_path, name)
    variable = {"twin": "TWIN_DATA_BASE_URL", "multidic": "MULTIDIC_BASE_URL"}[name]
    for k, (args, env) in enumerate(((["--base-url", mirror.as_uri()], {}), ([], {variable: str(mirror)}))):
        dest = tmp_path / f"dest{k}"
        proc = _run(name, *args, "--dest", str(dest), env=env)
        assert proc.returncode == 0, proc.stderr
        assert DONE[name].search(proc.stdout)
        assert mirror.as_uri() in (dest / "SOURCE.txt").read_text()
        fetched = [p for p in dest.rglob("*") if p.is_file() and p.name != "SOURCE.txt"]
        assert len(fetched) == len(_repository_paths(name))
        # every file is its mirror copy (the twin data's DICe licence is renamed LICENSE.txt)
        texts = {p.read_text() for p in fetched}
        assert texts == {f"fake {rel}\n" for rel in _repository_paths(name)}
        assert not list(dest.rglob("*.part"))


def test_base_url_and_git_mirror_together_are_refused(tmp_path):
    proc = _run("twin", "--base-url", tmp_path.as_uri(), "--mirror", str(tmp_path), "--dest", str(tmp_path / "d"))
    assert proc.returncode == 2 and "--mirror and --base-url" in proc.stderr


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_a_git_mirror_that_lacks_a_file_stops_the_script_naming_the_file(tmp_path, name):
    """The ``--mirror GIT_DIR`` path: a commit without one of the files stops the script, naming it."""
    work = _mirror(tmp_path, name, missing=MISSING[name])
    if name == "multidic":
        (work / "sample_data" / "BAcheckerboardImages" / "201").mkdir(parents=True, exist_ok=True)
    git = ["git", "-C", str(work), "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    for args in (["init", "-q"], ["add", "-A"], ["commit", "-q", "-m", "mirror"]):
        subprocess.run(git + args, check=True, capture_output=True)
    dest = tmp_path / "dest"
    proc = _run(name, "--mirror", str(work / ".git"), "--dest", str(dest))
    assert proc.returncode == 1, proc.stdout
    assert f"could not fetch {MISSING[name]}: not in the git mirror" in proc.stderr
    assert not DONE[name].search(proc.stdout)
    assert not (dest / "SOURCE.txt").exists()
