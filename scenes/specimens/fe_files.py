"""A user's specimen from files: a surface mesh or an FE result with nodal displacements over time steps.

One entry, :func:`read_specimen_file`, for every format users bring:

* surface meshes through trimesh: STL, PLY, OBJ, OFF, GLB/GLTF (triangles; no displacement);
* FE results through meshio: VTU/VTK, Gmsh ``.msh``, Abaqus ``.inp``, XDMF, ... (one state each; a ParaView
  ``.pvd`` collection lists one such file per time step);
* Exodus II (``.e``, ``.exo``: MOOSE, pyvale, DICe, Cubit) read here with netCDF4, every time step, since
  meshio reads only the first.

Volume meshes give their outer surface (:meth:`scenes.specimens.surface_mesh.SurfaceMesh.from_volume_cells`), surface
meshes their faces. Displacements are the file's own nodal field, named by the user (or found when the name is
unambiguous; the message lists what the file has), over the time steps chosen by index or by time. Lengths
are converted with the stated unit, and a unit that looks wrong from the mesh's size is refused by name: an FE
model of a lab specimen in metres read as millimetres is a few thousandths of a millimetre across.

:func:`write_exodus` writes an Exodus II file with every time step (what the catalog's FE models are saved as).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenes.specimens.face_elements import FACE_ALIASES, FACE_ELEMENTS
from scenes.specimens.surface_mesh import MeshError, SurfaceMesh

#: Length units a file may be in, in mm.
UNITS_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3, "in": 25.4}
#: A specimen smaller than this (largest bounding-box side, mm, after the unit) is refused as a unit error.
MIN_SIZE_MM = 0.5
#: ... and one larger than this.
MAX_SIZE_MM = 5_000.0
TRIMESH_SUFFIXES = (".stl", ".ply", ".obj", ".off", ".glb", ".gltf")
EXODUS_SUFFIXES = (".e", ".exo", ".ex2", ".exii")
#: Exodus element types -> meshio cell names (node order as VTK after :data:`_EXODUS_ORDER`).
EXODUS_TYPES = {"TETRA": "tetra", "TETRA4": "tetra", "TET4": "tetra", "TET": "tetra", "TETRA10": "tetra10",
                "TET10": "tetra10", "HEX": "hexahedron", "HEX8": "hexahedron", "HEXAHEDRON": "hexahedron",
                "HEX20": "hexahedron20", "WEDGE": "wedge", "WEDGE6": "wedge", "TRI": "triangle", "TRI3": "triangle",
                "TRIANGLE": "triangle", "TRISHELL": "triangle", "TRISHELL3": "triangle", "TRI6": "triangle6",
                "TRISHELL6": "triangle6", "QUAD": "quad", "QUAD4": "quad", "SHELL": "quad", "SHELL4": "quad",
                "QUAD8": "quad8", "SHELL8": "quad8", "QUAD9": "quad9", "SHELL9": "quad9"}
#: Exodus orders HEX20's vertical mid-edge nodes before the top ones; VTK after.
_EXODUS_ORDER = {"hexahedron20": [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 16, 17, 18, 19, 12, 13, 14, 15]}
VOLUME_TYPES = ("tetra", "tetra10", "hexahedron", "hexahedron20", "hexahedron27", "wedge")


class SpecimenFileError(ValueError):
    """A specimen file that cannot be used (the message names the file and the field, step or unit at fault)."""


@dataclass(frozen=True)
class SpecimenFile:
    """What a specimen file holds, converted to mm.

    Attributes
    ----------
    mesh : SurfaceMesh, the outer surface, specimen frame (= the file's axes), mm
    displacements_mm : (K, P, 3) nodal displacements of the chosen steps (K = 0 for a bare surface mesh)
    times : (K,) the steps' times as the file gives them (their indices where it gives none)
    step_indices : (K,) the steps' indices in the file
    field_name : the displacement field read (None without displacements)
    source : the file
    unit : the file's length unit
    info : what else is worth stating (cell counts, available fields and steps)
    """

    mesh: SurfaceMesh
    displacements_mm: np.ndarray
    times: np.ndarray
    step_indices: np.ndarray
    field_name: str | tuple | None
    source: str
    unit: str
    info: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------------------
def read_specimen_file(path, *, unit: str = "mm", displacement: str | tuple | None = None, steps=None,
                       times=None, file_format: str | None = None, towards_mm=None) -> SpecimenFile:
    """Read a specimen surface and its nodal displacements (module docstring).

    Parameters
    ----------
    path : the file
    unit : the file's length unit (:data:`UNITS_MM`); checked against the mesh size
    displacement : the nodal displacement field: a vector field name, or three scalar field names (x, y, z); None
        finds the one field named like a displacement (``displacement``, ``disp``, ``u``, ...) or the only vector
    steps : time-step indices to read (negative from the end; default all); ``times``: or the steps nearest to
        these times (each must match a step's time to 1e-9 relative)
    file_format : meshio's format name where the suffix does not tell
    towards_mm : a point (file frame, the file's unit) an open surface mesh should face (see
        :meth:`SurfaceMesh.from_surface_cells`)

    Raises
    ------
    SpecimenFileError
        Naming the file and: a missing file, an unreadable one, no faces, a displacement field that is missing
        (the available ones listed), of the wrong node count or not finite, a missing step or time (the available
        ones listed), a unit that does not fit the mesh's size.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise SpecimenFileError(f"{path}: no such file")
    if unit not in UNITS_MM:
        raise SpecimenFileError(f"{path}: unit {unit!r} is not one of {', '.join(UNITS_MM)}")
    if steps is not None and times is not None:
        raise SpecimenFileError(f"{path}: give steps or times, not both")
    scale = UNITS_MM[unit]
    suffix = Path(path).suffix.lower()
    if suffix in TRIMESH_SUFFIXES and file_format is None:
        points, cells, fields, file_times = _read_trimesh(path)
    elif suffix in EXODUS_SUFFIXES or (file_format or "").lower() == "exodus":
        points, cells, fields, file_times = _read_exodus(path)
    elif suffix == ".pvd":
        points, cells, fields, file_times = _read_pvd(path)
    else:
        points, cells, fields, file_times = _read_meshio(path, file_format)
    planar = _planar(points, fields)
    _check_size(path, points * scale, unit)
    volume = {k: v for k, v in cells.items() if k in VOLUME_TYPES and len(v)}
    try:
        if volume:
            mesh = SurfaceMesh.from_volume_cells(points * scale, volume, source=path)
        else:
            towards = None if towards_mm is None else np.asarray(towards_mm, float) * scale
            mesh = SurfaceMesh.from_surface_cells(points * scale, cells, source=path, towards_mm=towards)
    except MeshError as err:
        found = ", ".join(f"{len(v)} {k}" for k, v in cells.items()) or "no cells"
        raise SpecimenFileError(f"{err} (the file has {found})") from None
    info = {"cells": {k: int(len(v)) for k, v in cells.items()}, "fields": sorted(_field_names(fields, len(points))),
            **({"two_dimensional": planar} if planar else {}),
            "n_steps_in_file": int(len(file_times)), "faces": {k: int(len(v)) for k, v in mesh.faces.items()}}
    if not fields:
        if displacement is not None:
            raise SpecimenFileError(f"{path}: no nodal fields in the file; the displacement {displacement!r} is not there")
        return SpecimenFile(mesh, np.zeros((0, len(points), 3)), np.zeros(0), np.zeros(0, np.int64), None, path, unit,
                            info)
    chosen = _choose_steps(path, file_times, steps, times)
    if displacement is None:
        try:
            displacement_field_name(fields[0], len(points), None, path)
        except ValueError as err:
            if "missing" in str(err):       # fields, none of them a displacement: a rigid specimen, said
                import warnings
                warnings.warn(f"{path}: no nodal field is named like a displacement (fields: "
                              f"{', '.join(sorted(fields[0]))}); the specimen is rigid unless you name its field",
                              stacklevel=2)
                info["no_displacement_field"] = True
                return SpecimenFile(mesh, np.zeros((0, len(points), 3)), np.zeros(0), np.zeros(0, np.int64), None,
                                    path, unit, info)
    name = _pick_field(path, fields[0], len(points), displacement)
    U = np.stack([_field_vector(path, fields[k], name, len(points), k) for k in chosen]) * scale
    return SpecimenFile(mesh, U, np.asarray(file_times)[chosen], np.asarray(chosen, np.int64), name, path, unit, info)


def _planar(points: np.ndarray, fields: list) -> list:
    """A 2-D model (every z = 0): each in-plane displacement pair ``<name>_x, <name>_y`` gets ``<name>_z = 0``, so
    it reads as any 3-D field. Returns the names added."""

    if not len(points) or np.any(points[:, 2] != 0) or not fields:
        return []
    added = set()
    for step in fields:
        groups: dict = {}
        for key in list(step):
            m = COMPONENT_PATTERN.match(key)
            if m:
                groups.setdefault(m.group(1), {})[m.group(2).lower()] = key
        for base, g in groups.items():
            if set(g) == {"x", "y"}:
                name = g["x"][:-1] + ("z" if g["x"][-1] == "x" else "Z")
                step[name] = np.zeros(np.size(step[g["x"]]))
                added.add(name)
    return sorted(added)


def _check_size(path: str, points_mm: np.ndarray, unit: str) -> None:
    size = float(np.max(np.ptp(points_mm, axis=0))) if len(points_mm) else 0.0
    if size < MIN_SIZE_MM:
        hint = " in metres? give unit = \"m\"" if unit == "mm" else ""
        raise SpecimenFileError(f"{path}: the mesh is {size:.3g} mm across read as {unit!r}; a specimen that small "
                                f"is a unit error (is the file{hint})")
    if size > MAX_SIZE_MM:
        raise SpecimenFileError(f"{path}: the mesh is {size:.3g} mm across read as {unit!r}; too large for a lab "
                                f"specimen (is the unit right?)")


def _field_names(fields: list, n_points: int) -> set:
    return set(fields[0]) if fields else set()


def _choose_steps(path: str, file_times, steps, times) -> list[int]:
    n = len(file_times)
    listing = ", ".join(f"{k}: t={t:g}" for k, t in enumerate(file_times[:20])) + (" ..." if n > 20 else "")
    if times is not None:
        out = []
        for t in np.atleast_1d(np.asarray(times, float)):
            d = np.abs(np.asarray(file_times, float) - t)
            k = int(np.argmin(d))
            if d[k] > 1e-9 * max(1.0, abs(t)):
                raise SpecimenFileError(f"{path}: no time step at time {t:g}; the file has {n} steps ({listing})")
            out.append(k)
        return out
    if steps is None:
        return list(range(n))
    out = []
    for k in np.atleast_1d(steps):
        if int(k) != k or not -n <= int(k) < n:
            shown = int(k) if int(k) == k else k
            raise SpecimenFileError(f"{path}: no time step {shown}; the file has {n} steps ({listing})")
        out.append(int(k) % n)
    return out


def _pick_field(path: str, fields0: dict, n_points: int, name):
    """The displacement's name: as given (checked), or the one unambiguous candidate."""

    try:
        return displacement_field_name(fields0, n_points, name, path)
    except ValueError as err:
        raise SpecimenFileError(str(err)) from None


def _field_vector(path: str, fields_k: dict, name, n_points: int, k: int) -> np.ndarray:

    try:
        U = displacement_array(fields_k, n_points, name, f"{path} (step {k})")
    except ValueError as err:
        raise SpecimenFileError(str(err)) from None
    if not np.all(np.isfinite(U)):
        bad = np.flatnonzero(~np.all(np.isfinite(U), axis=1))
        raise SpecimenFileError(f"{path}: displacement {name!r} at step {k} is not finite at {len(bad)} nodes "
                                f"(first: node {bad[0]})")
    return U


# ------------------------------------------------------------------------------------------------------------
def _read_trimesh(path: str):
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
        if hasattr(loaded, "merge_vertices"):
            loaded.merge_vertices()        # STL repeats each triangle's corners: neighbours must share them
    except Exception as exc:                               # trimesh raises many types on bad files
        raise SpecimenFileError(f"{path}: not a mesh file trimesh can read ({type(exc).__name__}: {exc})") from exc
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        raise SpecimenFileError(f"{path}: the mesh has no faces")
    return np.asarray(loaded.vertices, float), {"triangle": faces}, [], np.zeros(0)


def _read_meshio(path: str, file_format: str | None):
    import meshio

    try:
        mesh = meshio.read(path, file_format=file_format)
    except (Exception, SystemExit) as exc:          # meshio raises many types, and exits on some unreadable files
        raise SpecimenFileError(f"{path}: not a mesh file meshio can read ({type(exc).__name__}: {exc})") from exc
    return _from_meshio(path, mesh)


def _from_meshio(path: str, mesh):
    points = np.asarray(mesh.points, float)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise SpecimenFileError(f"{path}: node coordinates of shape {points.shape}")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    cells: dict[str, list] = {}
    for block in mesh.cells:
        name = FACE_ALIASES.get(block.type, {"tetra4": "tetra", "hexahedron8": "hexahedron"}.get(block.type, block.type))
        if name in VOLUME_TYPES or name in FACE_ELEMENTS:
            cells.setdefault(name, []).append(np.asarray(block.data, np.int64))
    cells = {k: np.concatenate(v) for k, v in cells.items()}
    if not cells:
        found = ", ".join(sorted({b.type for b in mesh.cells})) or "no cells"
        raise SpecimenFileError(f"{path}: no faces or volume cells of a supported type (surface: "
                                f"{', '.join(FACE_ELEMENTS)}; volume: {', '.join(VOLUME_TYPES)}); the file has: {found}")
    # meshio's bookkeeping arrays (gmsh:dim_tags, medit:ref, ...) are not fields of the result
    data = {k: v for k, v in mesh.point_data.items() if ":" not in k}
    fields = [data] if data else []
    return points, cells, fields, np.zeros(len(fields))


def specimen_file_set(path) -> list[Path]:
    """The files one specimen file stands for: itself, and for a ``.pvd`` collection every file it lists (to copy a
    specimen whole)."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    if path.suffix.lower() != ".pvd":
        return [path]
    try:
        sets = ET.parse(path).getroot().findall(".//DataSet")
    except ET.ParseError as exc:
        raise SpecimenFileError(f"{path}: not a readable .pvd collection ({exc})") from exc
    return [path] + [path.parent / s.get("file") for s in sets if s.get("file")]


def _read_pvd(path: str):
    """A ParaView collection: one mesh file per time step (same mesh), ``<DataSet timestep= file=>``."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise SpecimenFileError(f"{path}: not a readable .pvd collection ({exc})") from exc
    sets = root.findall(".//DataSet")
    if not sets:
        raise SpecimenFileError(f"{path}: the collection lists no <DataSet>")
    base = Path(path).parent
    entries = sorted(((float(s.get("timestep", k)), s.get("file")) for k, s in enumerate(sets)), key=lambda e: e[0])
    points = cells = None
    fields, file_times = [], []
    for t, name in entries:
        if not name:
            raise SpecimenFileError(f"{path}: a <DataSet> without file=")
        member = str(base / name)
        if not os.path.isfile(member):
            raise SpecimenFileError(f"{path}: lists {name}, which does not exist")
        p, c, f, _ = _read_meshio(member, None)
        if points is None:
            points, cells = p, c
        elif p.shape != points.shape or not np.allclose(p, points, rtol=0, atol=1e-9 * (1 + np.abs(points).max())):
            raise SpecimenFileError(f"{path}: {name} has another mesh than the first step (a moving mesh: give the "
                                    f"reference coordinates and displacements instead)")
        fields.append(f[0] if f else {})
        file_times.append(t)
    return points, cells, fields, np.asarray(file_times)


def _read_exodus(path: str):
    """Exodus II with netCDF4: coordinates, element blocks, nodal variables at every time step."""
    try:
        import netCDF4
    except ImportError as exc:          # a dependency of the project; a broken install says so
        raise SpecimenFileError(f"{path}: reading Exodus needs netCDF4 (pip install netCDF4)") from exc
    try:
        ds = netCDF4.Dataset(path, "r")
    except OSError as exc:
        raise SpecimenFileError(f"{path}: not a readable Exodus (netCDF) file ({exc})") from exc
    with ds:
        ds.set_auto_mask(False)
        v = ds.variables
        if "coord" in v:
            C = np.asarray(v["coord"][:], float)
            points = C.T
        elif "coordx" in v:
            points = np.column_stack([np.asarray(v[f"coord{a}"][:], float) for a in "xyz" if f"coord{a}" in v])
        else:
            raise SpecimenFileError(f"{path}: no node coordinates (coord or coordx/coordy/coordz)")
        if points.shape[1] == 2:
            points = np.column_stack([points, np.zeros(len(points))])
        cells: dict[str, list] = {}
        found = []
        names = sorted((k for k in v if k.startswith("connect") and k[7:].isdigit()), key=lambda k: int(k[7:]))
        for key in names:
            etype = str(getattr(v[key], "elem_type", "")).upper()
            found.append(etype)
            if etype in ("HEX27", "TETRA14", "TETRA15", "WEDGE15", "WEDGE18"):
                raise SpecimenFileError(f"{path}: {etype} elements from Exodus are not read (their mid-face node order "
                                        f"is not VTK's); export the result as VTU, or use HEX20/TETRA10")
            name = EXODUS_TYPES.get(etype)
            if name is None:
                continue
            conn = np.asarray(v[key][:], np.int64) - 1
            if name in _EXODUS_ORDER:
                conn = conn[:, _EXODUS_ORDER[name]]
            cells.setdefault(name, []).append(conn)
        if not cells:
            raise SpecimenFileError(f"{path}: no element block of a supported type (Exodus {', '.join(EXODUS_TYPES)}); "
                                    f"the file has: {', '.join(found) or 'no blocks'}")
        var_names = []
        if "name_nod_var" in v:
            var_names = [_chars(row) for row in np.asarray(v["name_nod_var"][:])]
        times = np.asarray(v["time_whole"][:], float) if "time_whole" in v else np.zeros(0)
        fields = []
        if var_names:
            n_t = max(len(times), 1)
            values = []
            for i, name in enumerate(var_names):
                if f"vals_nod_var{i + 1}" in v:
                    values.append(np.asarray(v[f"vals_nod_var{i + 1}"][:], float).reshape(n_t, -1))
                elif "vals_nod_var" in v:
                    values.append(np.asarray(v["vals_nod_var"][:, i, :], float).reshape(n_t, -1))
                else:
                    raise SpecimenFileError(f"{path}: nodal variable {name!r} has no values")
            fields = [{name: values[i][k] for i, name in enumerate(var_names)} for k in range(n_t)]
            if not len(times):
                times = np.zeros(1)
    return points, {k: np.concatenate(c) for k, c in cells.items()}, fields, times if fields else np.zeros(0)


def _chars(row) -> str:
    a = np.asarray(row)
    if a.dtype.kind == "S":
        return b"".join(a.ravel().tolist()).decode("ascii", "replace").rstrip("\x00 ").strip()
    return "".join(str(c) for c in a.ravel()).rstrip("\x00 ").strip()


# ------------------------------------------------------------------------------------------------------------
# the names meshio reads back as the same cell types (meshio maps "TETRA4" to a type it does not know)
_EXODUS_NAMES = {"tetra": "TETRA", "tetra10": "TETRA10", "hexahedron": "HEX8", "hexahedron20": "HEX20",
                 "wedge": "WEDGE6", "triangle": "TRI3", "triangle6": "TRI6", "quad": "QUAD4", "quad8": "QUAD8",
                 "quad9": "QUAD9"}


def write_exodus(path, points, cells: dict, displacements, times=None, *, field: str = "disp",
                 title: str = "scheimpflug-dic-workbench FE result") -> None:
    """Write an Exodus II file: coordinates, one block per cell type, the displacement as nodal variables
    ``<field>_x``, ``<field>_y``, ``<field>_z`` at every time step (the convention of MOOSE's output).

    Parameters
    ----------
    points : (P, 3) node coordinates (the caller's unit)
    cells : dict meshio cell type -> (E, n) node indices, VTK order
    displacements : (K, P, 3) nodal displacements per step
    times : (K,) step times (default 0, 1, ...)

    Written atomically (a temporary file renamed into place).
    """
    import netCDF4

    from labio.atomic import atomic_path

    P = np.asarray(points, float)
    U = np.asarray(displacements, float)
    if U.ndim != 3 or U.shape[1:] != P.shape:
        raise ValueError(f"displacements must be (K, {len(P)}, 3), got {U.shape}")
    T = np.arange(len(U), dtype=float) if times is None else np.asarray(times, float)
    inverse = {"hexahedron20": np.argsort(_EXODUS_ORDER["hexahedron20"])}
    unsupported = sorted(set(cells) - set(_EXODUS_NAMES))
    if unsupported:
        raise ValueError(f"{path}: cannot write {', '.join(unsupported)} cells to Exodus (write VTU instead)")
    with atomic_path(path) as tmp:
        with netCDF4.Dataset(str(tmp), "w", clobber=True, format="NETCDF3_64BIT_OFFSET") as ds:
            ds.title = title
            ds.api_version = np.float32(8.0)
            ds.version = np.float32(8.0)
            ds.floating_point_word_size = np.int32(8)
            ds.file_size = np.int32(1)
            ds.createDimension("len_string", 33)
            ds.createDimension("len_line", 81)
            ds.createDimension("four", 4)
            ds.createDimension("time_step", None)
            ds.createDimension("num_dim", 3)
            ds.createDimension("num_nodes", len(P))
            ds.createDimension("num_elem", sum(len(c) for c in cells.values()))
            ds.createDimension("num_el_blk", len(cells))
            ds.createDimension("num_nod_var", 3)
            tw = ds.createVariable("time_whole", "f8", ("time_step",))
            tw[:] = T
            for a, axis in enumerate("xyz"):
                c = ds.createVariable(f"coord{axis}", "f8", ("num_nodes",))
                c[:] = P[:, a]
            names = ds.createVariable("coor_names", "S1", ("num_dim", "len_string"))
            names[:] = netCDF4.stringtochar(np.array(["x", "y", "z"], dtype="S33"))
            ids = ds.createVariable("eb_prop1", "i4", ("num_el_blk",))
            ids.setncattr("name", "ID")
            ids[:] = np.arange(1, len(cells) + 1)
            status = ds.createVariable("eb_status", "i4", ("num_el_blk",))
            status[:] = 1
            for b, (name, conn) in enumerate(cells.items(), start=1):
                conn = np.asarray(conn, np.int64)
                if name in inverse:
                    conn = conn[:, inverse[name]]
                ds.createDimension(f"num_el_in_blk{b}", len(conn))
                ds.createDimension(f"num_nod_per_el{b}", conn.shape[1])
                var = ds.createVariable(f"connect{b}", "i4", (f"num_el_in_blk{b}", f"num_nod_per_el{b}"))
                var.elem_type = _EXODUS_NAMES[name]
                var[:] = conn + 1
            vn = ds.createVariable("name_nod_var", "S1", ("num_nod_var", "len_string"))
            vn[:] = netCDF4.stringtochar(np.array([f"{field}_{a}" for a in "xyz"], dtype="S33"))
            for a in range(3):
                var = ds.createVariable(f"vals_nod_var{a + 1}", "f8", ("time_step", "num_nodes"))
                var[:] = U[:, :, a]


# ------------------------------------------------------------------------------------------------------------
# Which point-data array is the displacement
_DISPLACEMENT_NAMES = re.compile(r"^(u|d|disp|displ|displacement|displacements|deformation|dis)$", re.IGNORECASE)
_COMPONENT = re.compile(r"^(.*?)[_\-:. ]?([xyzXYZ])$")
#: Public: how a scalar field names its component (``disp_x``, ``ux``, ``U:X``).
COMPONENT_PATTERN = _COMPONENT


def displacement_field_name(point_data: dict, n_points: int, name, source: str) -> str | tuple[str, str, str]:
    """The nodal displacement among meshio-style point data: ``name`` checked (a (P, 3) array, or three scalar
    arrays x, y, z), or, for None, the one vector array named like a displacement (``displacement``, ``disp``,
    ``u``, ...), the one such scalar triplet (``disp_x``, ``disp_y``, ``disp_z``) or the only (P, 3) array.

    Raises ValueError naming ``source`` and listing the available arrays when it is missing or ambiguous."""
    def describe():
        items = [f"{k} {tuple(np.shape(v))}" for k, v in point_data.items()]
        return ", ".join(items) if items else "none"

    def vector(key):
        shape = np.shape(point_data[key])
        if shape != (n_points, 3):
            raise ValueError(f"{source}: point data {key!r} has shape {shape}, not ({n_points}, 3) displacements; "
                             f"available point data: {describe()}")
        return key

    if isinstance(name, (tuple, list)):
        missing = [k for k in name if k not in point_data]
        if len(name) != 3 or missing:
            raise ValueError(f"{source}: displacement components {tuple(name)} not found (missing {missing}); "
                             f"available point data: {describe()}")
        for k in name:
            if np.size(point_data[k]) != n_points:
                raise ValueError(f"{source}: point data {k!r} has {np.size(point_data[k])} values for {n_points} "
                                 f"nodes; available point data: {describe()}")
        return tuple(name)
    if name is not None:
        if name not in point_data:
            raise ValueError(f"{source}: no point data named {name!r}; available point data: {describe()}")
        return vector(name)
    vectors = [k for k, v in point_data.items() if np.shape(v) == (n_points, 3)]
    named = [k for k in vectors if _DISPLACEMENT_NAMES.match(k)]
    # Scalar triplets such as disp_x, disp_y, disp_z.
    groups: dict[str, dict[str, str]] = {}
    for k, v in point_data.items():
        m = _COMPONENT.match(k)
        if m and np.size(v) == n_points:
            groups.setdefault(m.group(1), {})[m.group(2).lower()] = k
    triplets = {b: (g["x"], g["y"], g["z"]) for b, g in groups.items() if set(g) == {"x", "y", "z"}}
    named_triplets = [b for b in triplets if _DISPLACEMENT_NAMES.match(b)]
    if len(named) == 1:
        return vector(named[0])
    if not named and len(named_triplets) == 1:
        return triplets[named_triplets[0]]
    if not named and not named_triplets and len(vectors) == 1:
        return vector(vectors[0])
    what = "ambiguous" if (len(named) > 1 or len(vectors) > 1 or len(named_triplets) > 1) else "missing"
    raise ValueError(f"{source}: nodal displacement {what}; name it (displacement_name=, or a specimen's field =) "
                     f"among the point data arrays (available point data: {describe()})")


def displacement_array(point_data: dict, n_points: int, name, source: str) -> np.ndarray:
    """The (P, 3) nodal displacement :func:`displacement_field_name` names, as float."""
    key = displacement_field_name(point_data, n_points, name, source)
    if isinstance(key, tuple):
        return np.stack([np.asarray(point_data[k], dtype=float).reshape(n_points) for k in key], axis=1)
    return np.asarray(point_data[key], dtype=float)

