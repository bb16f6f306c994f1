"""The package boundaries of docs/architecture.rst, checked on the source (AST, no import): truth and instrument
never import each other, the workbench's truth writers never import the instrument, the rooms of ``scenes/``
and of ``workbench/`` import only downwards, no module of ``scenes/`` exceeds 600 lines, no import circle anywhere, and no module imports another module's private name.

Each rule is also checked on a deliberately broken copy of the tree (a forbidden import added), so a rule that
cannot fail is itself a failure.
"""
from __future__ import annotations

import ast
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("labio", "scenes", "measurement", "workbench")

#: What each top-level package may import from the project (besides itself).
ALLOWED = {"labio": set(), "scenes": {"labio"}, "measurement": {"labio"},
           "workbench": {"labio", "scenes", "measurement"}}
#: Third-party packages a package must not import (the instrument runs on real images, without the renderer).
FORBIDDEN_THIRD_PARTY = {"measurement": {"mitsuba", "drjit"}, "labio": {"mitsuba", "drjit"}}
#: The rooms of scenes/, lowest first ("" = the package's own top-level modules: _checks, _legacy).
SCENE_ROOMS = ("", "optics", "surfaces", "deformation", "specimens", "sensor", "rendering", "image_pairs")
#: The only modules of scenes/ outside a room: the package itself, its shared checks, the old paths' shim.
SCENE_TOP_LEVEL = ("scenes", "scenes._checks", "scenes._legacy")
#: Longest module of scenes/, lines (one algorithm per module, readable alone).
SCENE_MODULE_LINES = 600
#: The rooms of workbench/, lowest first: a module imports only from its own room or a lower one.
ROOMS = ("core", "reporting", "experiments", "studies", "twin", "design", "scoring", "commands", "cli")
#: The workbench's truth writers (scene builders): they compute truth with scenes/ only, never the instrument.
TRUTH_WRITERS = ("workbench/experiments/*/scenes.py", "workbench/experiments/calibration/views.py",
                 "workbench/truth_schema.py", "workbench/twin/scene.py")


def modules(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every module of the project's packages under ``root``."""
    found = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def imports(name: str, path: Path, known: dict[str, Path]) -> list[tuple[str, str | None, int]]:
    """(imported module, imported name or None, line) of every import in a module, relative ones resolved.
    ``from pkg import mod`` counts as an import of ``pkg.mod``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(alias.name, None, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                full = f"{target}.{alias.name}"
                out.append((full, None, node.lineno) if full in known else (target, alias.name, node.lineno))
    return out


def room(module: str) -> str:
    """The room of a workbench module: its sub-package, ``core`` for top-level modules (and peers/)."""
    parts = module.split(".")
    if module == "workbench.cli":
        return "cli"
    if len(parts) > 2 or (len(parts) == 2 and parts[1] in ROOMS):
        return parts[1] if parts[1] in ROOMS else "core"
    return "core"


def scene_room(module: str) -> str:
    """The room of a scenes module: its sub-package, "" for the package's own top-level modules."""
    parts = module.split(".")
    if len(parts) >= 3 or (len(parts) == 2 and parts[1] in SCENE_ROOMS):
        return parts[1]
    return ""


def violations(root: Path) -> list[str]:
    """Every broken rule in the tree under ``root``, one line each."""
    known = modules(root)
    found, graph = [], {m: set() for m in known}
    truth_writers = {p for pattern in TRUTH_WRITERS for p in root.glob(pattern)}
    for name, path in known.items():
        top = name.split(".")[0]
        where = f"{path.relative_to(root)}"
        truth_writer = path in truth_writers
        for target, imported, line in imports(name, path, known):
            head = target.split(".")[0]
            if head in FORBIDDEN_THIRD_PARTY.get(top, ()):
                found.append(f"{where}:{line}: {top}/ imports {head}")
            if head not in PACKAGES:
                continue
            if head != top and head not in ALLOWED[top]:
                found.append(f"{where}:{line}: {top}/ imports {target}")
            if truth_writer and head == "measurement":
                found.append(f"{where}:{line}: a truth writer imports the instrument ({target})")
            if target in known and target != name:
                graph[name].add(target)
            if imported and imported.startswith("_") and not imported.startswith("__") and target != name:
                found.append(f"{where}:{line}: imports the private name {imported} of {target}")
            if top == head == "scenes" and target in known:
                mine, theirs = scene_room(name), scene_room(target)
                if mine in SCENE_ROOMS and theirs in SCENE_ROOMS and SCENE_ROOMS.index(theirs) > SCENE_ROOMS.index(mine):
                    found.append(f"{where}:{line}: scenes room {mine} imports {target} of the higher room {theirs}")
            if top == head == "workbench" and target in known:
                if ROOMS.index(room(target)) > ROOMS.index(room(name)):
                    found.append(f"{where}:{line}: room {room(name)} imports {target} of the higher room "
                                 f"{room(target)}")
    found += [f"import circle: {' -> '.join(c)}" for c in circles(graph)]
    for name, path in known.items():
        if name.split(".")[0] != "scenes":
            continue
        if scene_room(name) not in SCENE_ROOMS or (scene_room(name) == "" and name not in SCENE_TOP_LEVEL):
            found.append(f"{path.relative_to(root)}: in no room of scenes/ ({', '.join(SCENE_ROOMS[1:])})")
        if len(path.read_text().splitlines()) > SCENE_MODULE_LINES:
            found.append(f"{path.relative_to(root)}: {len(path.read_text().splitlines())} lines, over "
                         f"{SCENE_MODULE_LINES} (split it by algorithm)")
    return found


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_project_keeps_its_boundaries():
    """No truth/instrument crossing, no upward import between rooms, no circle, no private name imported."""
    assert violations(ROOT) == []


@pytest.fixture(scope="module")
def copy_of_tree(tmp_path_factory):
    """A copy of the four packages' sources, to break on purpose."""
    out = tmp_path_factory.mktemp("tree")
    for package in PACKAGES:
        shutil.copytree(ROOT / package, out / package, ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    return out


BREAKS = {
    "scenes imports measurement": ("scenes/surfaces/speckle.py", "from measurement.camera import ScheimpflugCamera\n",
                                   "scenes/ imports measurement.camera"),
    "measurement imports scenes": ("measurement/stereo.py", "import scenes.optics.projection\n", "measurement/ imports scenes.optics.projection"),
    "measurement imports workbench": ("measurement/stereo.py", "from workbench import rigs\n",
                                      "measurement/ imports workbench.rigs"),
    "measurement imports mitsuba": ("measurement/stereo.py", "import mitsuba\n", "measurement/ imports mitsuba"),
    "a circle": ("workbench/rigs.py", "from workbench import poses\n", "import circle: workbench.poses -> workbench.rigs"),
    "an upward import in scenes": ("scenes/specimens/plate.py", "from scenes.rendering import exact\n",
                                   "scenes room specimens imports scenes.rendering.exact of the higher room rendering"),
    "a module outside the rooms of scenes": ("scenes/extra.py", "import numpy\n", "in no room of scenes/"),
    "an oversized scenes module": ("scenes/optics/mtf.py", "\n" * 600, "lines, over 600"),
    "an upward import": ("workbench/experiments/rigid_motion/run.py", "from workbench.scoring import gate\n",
                         "room experiments imports workbench.scoring.gate of the higher room scoring"),
    "a private name": ("workbench/poses.py", "from workbench.rigs import _warn_if_tiny\n",
                       "imports the private name _warn_if_tiny of workbench.rigs"),
    "truth from the instrument": ("workbench/experiments/calibration/views.py",
                                  "from measurement.camera import ScheimpflugCamera\n",
                                  "a truth writer imports the instrument (measurement.camera)"),
}


@pytest.mark.parametrize("what", sorted(BREAKS))
def test_a_deliberately_added_forbidden_import_is_caught(copy_of_tree, what):
    """Each rule fails on a copy of the tree with one forbidden import added (and the copy is restored)."""
    file, line, expected = BREAKS[what]
    path = copy_of_tree / file
    original = path.read_text() if path.exists() else None
    try:
        path.write_text(line + (original or ""))
        found = violations(copy_of_tree)
    finally:
        if original is None:
            path.unlink()
        else:
            path.write_text(original)
    assert any(expected in v for v in found), found
    assert violations(copy_of_tree) == []


def test_the_flat_paths_of_scenes_before_its_rooms_still_import_with_a_warning():
    """Users' ``from scenes.truth import ...`` (issue 41 moved it) gives the same object and a DeprecationWarning
    naming where it lives now; each room's package answers its old flat module's names the same way; a name that
    went says what replaces it."""
    import importlib
    import sys

    from scenes.optics.mtf import Optics
    from scenes.optics.projection import project_points
    from scenes.surfaces.dot_grid import DotGrid

    for name in ("scenes.truth", "scenes.targets", "scenes.fields"):
        sys.modules.pop(name, None)
    with pytest.warns(DeprecationWarning, match=r"scenes\.truth moved to scenes\.optics\.projection"):
        old = importlib.import_module("scenes.truth")
    assert old.project_points is project_points
    with pytest.warns(DeprecationWarning, match=r"scenes\.targets moved to .*scenes\.surfaces\.dot_grid"):
        assert importlib.import_module("scenes.targets").DotGrid is DotGrid
    with pytest.warns(DeprecationWarning, match=r"scenes\.optics\.Optics moved to scenes\.optics\.mtf\.Optics"):
        from scenes.optics import Optics as old_optics
    assert old_optics is Optics
    with pytest.warns(DeprecationWarning):
        fields = importlib.import_module("scenes.fields")
    with pytest.raises(AttributeError, match=r"scenes\.fields\.FEMeshField was removed: .*read_specimen_file"):
        fields.FEMeshField
