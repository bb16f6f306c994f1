"""Result files of DIC tools, read into one table in this project's conventions (:class:`ToolResult`).

Readers (``READERS``):

* ``native``: this project's ``workbench dic`` CSV (``x, y, u, v, …, status_name``) or stereo state CSV
  (``x, y, X, Y, Z, U, V, W, …, status_name``, :mod:`measurement.stereo_io`);
* ``dice``: DICe's solution text (``DICe_solution_*.txt``): comma-separated, optional ``***`` header lines,
  then ``SUBSET_ID, COORDINATE_X, COORDINATE_Y, DISPLACEMENT_X, DISPLACEMENT_Y, SIGMA, GAMMA, BETA,
  STATUS_FLAG, …``; stereo runs add ``MODEL_COORDINATES_X/Y/Z`` and ``MODEL_DISPLACEMENT_X/Y/Z`` (mm, in
  DICe's model frame: camera 0 unless a best-fit plane was asked for). A point DICe could not correlate has
  ``SIGMA = -1``;
* ``vic3d``: VIC-3D's / VIC-2D's CSV export (:mod:`workbench.readers.vic3d`);
* ``matchid``: MatchID's CSV export (:mod:`workbench.readers.matchid`);
* ``opencorr``: OpenCorr's 2-D or stereo result table (:mod:`workbench.readers.opencorr`);
* ``ncorr``, ``multidic``: Ncorr's and MultiDIC's MATLAB v7.3 result files, every state in one file
  (:mod:`workbench.readers.matlab`, read with :func:`read_results`);
* ``pyvale``: pyvale's 2-D DIC CSV (:mod:`workbench.peers.pyvale_engine`);
* ``auto``: the layout recognised from the header (every format above but ``csv``); a header that matches none
  is refused naming its columns and what each layout it could be lacks;
* ``csv``: any CSV by a column mapping ``x=..,y=..,u=..,v=..`` (and ``X,Y,Z,U,V,W`` for 3-D, ``valid`` for a
  0/1 or true/false column, ``exx, eyy, exy`` for 2-D Green-Lagrange strain with tensor shear), with the tool's
  pixel origin and length unit stated.

Conventions after reading: x = column, y = row of the LEFT REFERENCE image with pixel centres at integer
coordinates (OpenCV); 2-D displacement in px (deformed minus reference position); 3-D positions and
displacements in mm in the tool's frame (``frame`` says which; scoring aligns it, :mod:`workbench.scoring.metrics`).
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# the one table of a result, its error and the CSV helpers every reader shares (they live below the readers of the
# other tools, which this module dispatches to)
from workbench.readers.table import ResultFormatError, ToolResult, read_table, table_column

READERS = ("auto", "native", "dice", "vic3d", "matchid", "opencorr", "ncorr", "multidic", "pyvale", "csv")
#: Formats whose one file holds every state (read with :func:`read_results`).
MULTI_STATE = ("ncorr", "multidic")
#: Pixel-coordinate conventions of tools: what to add to their x, y to get OpenCV's (integer pixel centres).
PIXEL_ORIGINS = {"center": 0.0, "corner": -0.5, "one-based": -1.0}
#: Length units of 3-D columns, in mm.
LENGTH_UNITS_MM = {"mm": 1.0, "um": 1e-3, "m": 1e3}
#: Columns a mapping may name.
MAPPABLE = ("x", "y", "u", "v", "X", "Y", "Z", "U", "V", "W", "exx", "eyy", "exy", "valid")


def read_native(path: Path) -> ToolResult:
    """This project's 2-D (``workbench dic``) or stereo state CSV."""
    header, rows = read_table(path)
    col = lambda n: table_column(path, header, rows, n)  # noqa: E731
    names = [r[header.index("status_name")] for r in rows] if "status_name" in header else None
    x, y = col("x"), col("y")
    if "U" in header:
        X = np.column_stack([col("X"), col("Y"), col("Z")])
        U = np.column_stack([col("U"), col("V"), col("W")])
        valid = np.all(np.isfinite(U), axis=1)
        if names is not None:
            valid &= np.array([n == "converged" for n in names])
        sigma = None
        if "sigma_U_um" in header:
            sigma = np.column_stack([col(f"sigma_{c}_um") for c in "UVW"])
            if "sigma_U_calib_um" in header:
                calib = np.column_stack([col(f"sigma_{c}_calib_um") for c in "UVW"])
                sigma = np.sqrt(sigma ** 2 + np.where(np.isfinite(calib), calib, 0.0) ** 2)
            sigma = sigma * 1e-3
        strain = strain_sigma = window = None
        if "exx" in header:
            strain = np.column_stack([col(c) for c in ("exx", "eyy", "exy")])
            strain[~valid] = np.nan
            if "sigma_exx" in header:
                strain_sigma = np.column_stack([col(f"sigma_{c}") for c in ("exx", "eyy", "exy")])
            window = _native_strain_window(path)
        return ToolResult(path, "scheimpflug-dic-workbench", x, y, valid, X_mm=X, U_mm=U, sigma_U_mm=sigma,
                          surface_strain=strain, surface_strain_sigma=strain_sigma, strain_window=window)
    u, v = col("u"), col("v")
    valid = np.isfinite(u) & np.isfinite(v)
    if names is not None:
        valid &= np.array([n == "converged" for n in names])
    sigma = np.column_stack([col("sigma_u_px"), col("sigma_v_px")]) if "sigma_u_px" in header else None
    return ToolResult(path, "scheimpflug-dic-workbench", x, y, valid, u, v, sigma_uv_px=sigma)


def _native_strain_window(path: Path) -> dict | None:
    """The strain window a ``workbench stereo`` result was computed with (its folder's manifest), or None."""
    from workbench.manifest import DatasetFolderError, read_manifest

    try:
        manifest = read_manifest(path.parent)
    except DatasetFolderError:
        return None
    strain = (manifest or {}).get("settings", {}).get("strain") if (manifest or {}).get("kind") == "stereo" else None
    if not isinstance(strain, dict) or "window_points" not in strain:
        return None
    return {"window_points": strain["window_points"], "fit": strain.get("fit") or "linear"}


def read_dice(path: Path) -> ToolResult:
    """A DICe solution file (2-D, or stereo with MODEL_* columns)."""
    header, rows = read_table(path)
    header = [h.upper() for h in header]
    col = lambda n, what=None: table_column(path, header, rows, n, what=what)  # noqa: E731
    x, y = col("COORDINATE_X"), col("COORDINATE_Y")
    u, v = col("DISPLACEMENT_X"), col("DISPLACEMENT_Y")
    valid = np.isfinite(u) & np.isfinite(v)
    if "SIGMA" in header:
        valid &= col("SIGMA") >= 0.0          # DICe marks a point it could not correlate with SIGMA = -1
    u, v = np.where(valid, u, np.nan), np.where(valid, v, np.nan)
    X = U = None
    if "MODEL_DISPLACEMENT_X" in header:
        X = np.column_stack([col(f"MODEL_COORDINATES_{a}", "stereo position") for a in "XYZ"])
        U = np.column_stack([col(f"MODEL_DISPLACEMENT_{a}", "stereo displacement") for a in "XYZ"])
        X = X + U                              # MODEL_COORDINATES are the reference positions
        X[~valid], U[~valid] = np.nan, np.nan
    strain = None
    # DICe's virtual-strain-gauge post-processor; read as Green-Lagrange with tensor shear (an assumption to
    # check against your DICe version: a tool writing engineering shear needs exy / 2)
    if "VSG_STRAIN_XX" in header:
        strain = np.column_stack([col(f"VSG_STRAIN_{c}", "strain") for c in ("XX", "YY", "XY")])
        strain[~valid] = np.nan
    # DICe's SIGMA: its own estimate of the displacement's standard deviation (px), scored by its coverage
    sigma = None
    if "SIGMA" in header:
        sig = np.where(valid, col("SIGMA"), np.nan)
        sigma = np.column_stack([sig, sig])
    return ToolResult(path, "DICe", x, y, valid, u, v, X, U, frame="DICe model frame (camera 0)", strain=strain,
                      sigma_uv_px=sigma)


def read_pyvale(path: Path) -> ToolResult:
    from workbench.peers.pyvale_engine import read_result

    r = read_result(path)
    valid = np.asarray(r["valid"], bool)
    return ToolResult(path, r.get("tool", "pyvale"), np.asarray(r["x_px"], float), np.asarray(r["y_px"], float), valid,
                      np.where(valid, r["u_px"], np.nan), np.where(valid, r["v_px"], np.nan))


def parse_columns(text: str) -> dict[str, str]:
    """``"x=col_x,y=col_y,u=disp_x"`` -> ``{"x": "col_x", ...}``; names must be in :data:`MAPPABLE`."""
    mapping = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not value:
            raise ValueError(f"--columns {text!r}: {item!r} is not NAME=COLUMN")
        if key not in MAPPABLE:
            raise ValueError(f"--columns: {key!r} is not one of {', '.join(MAPPABLE)}")
        if key in mapping:
            raise ValueError(f"--columns: {key!r} is given twice")
        mapping[key] = value
    for need in ("x", "y"):
        if need not in mapping:
            raise ValueError(f"--columns {text!r}: names no {need} column (the reference position)")
    has2 = "u" in mapping and "v" in mapping
    has3 = all(k in mapping for k in "UVW")
    if not (has2 or has3):
        raise ValueError(f"--columns {text!r}: name u and v (2-D displacement, px) or U, V, W (3-D, the length unit)")
    if any(k in mapping for k in "XYZ") and not all(k in mapping for k in "XYZ"):
        raise ValueError("--columns: name all of X, Y, Z or none")
    return mapping


def read_mapped_csv(path: Path, columns: dict[str, str], pixel_origin: str = "center",
                    length_unit: str = "mm", strain_convention=None, ignore_strain: bool = False) -> ToolResult:
    """Any CSV by a column mapping (:func:`parse_columns`), converted from the stated conventions."""
    if pixel_origin not in PIXEL_ORIGINS:
        raise ValueError(f"--pixel-origin {pixel_origin!r}: choose one of {', '.join(PIXEL_ORIGINS)}")
    if length_unit not in LENGTH_UNITS_MM:
        raise ValueError(f"--length-unit {length_unit!r}: choose one of {', '.join(LENGTH_UNITS_MM)}")
    header, rows = read_table(path)
    col = lambda k: table_column(path, header, rows, columns[k], what=f"mapped to {k}")  # noqa: E731
    shift = PIXEL_ORIGINS[pixel_origin]
    x, y = col("x") + shift, col("y") + shift
    valid = np.ones(x.size, bool)
    if "valid" in columns:
        j = header.index(columns["valid"]) if columns["valid"] in header else None
        if j is None:
            raise ResultFormatError(f"{path}: no column {columns['valid']!r} (mapped to valid)")
        words = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}
        try:
            valid = np.array([words[r[j].strip().lower()] for r in rows], bool)
        except KeyError as err:
            raise ResultFormatError(f"{path}: column {columns['valid']!r} holds {err.args[0]!r}, not 0/1 or "
                                    "true/false") from None
    u = v = X = U = None
    if "u" in columns:
        u, v = col("u"), col("v")
        valid &= np.isfinite(u) & np.isfinite(v)
    if "U" in columns:
        scale = LENGTH_UNITS_MM[length_unit]
        U = np.column_stack([col(k) for k in "UVW"]) * scale
        valid &= np.all(np.isfinite(U), axis=1)
        if "X" in columns:
            X = np.column_stack([col(k) for k in "XYZ"]) * scale
    strain = None
    if any(k in columns for k in ("exx", "eyy", "exy")) and not ignore_strain:
        from workbench.readers.conventions import UnstatedStrainError, to_green_lagrange

        if not all(k in columns for k in ("exx", "eyy", "exy")):
            raise ValueError("--columns: name all of exx, eyy, exy or none")
        if strain_convention is None:
            raise UnstatedStrainError(f"{path}: --columns maps strain columns, but not their convention: give "
                                      "--strain-measure, --strain-shear and --strain-unit, or --ignore-strain")
        strain = to_green_lagrange(*(col(k) for k in ("exx", "eyy", "exy")), strain_convention)
    nanify = lambda a: None if a is None else np.where(valid if a.ndim == 1 else valid[:, None], a, np.nan)  # noqa: E731
    return ToolResult(path, "csv", x, y, valid, nanify(u), nanify(v), nanify(X), nanify(U), frame="as the tool states",
                      strain=nanify(strain))


def read_result(path: str | Path, fmt: str = "native", columns: str | None = None, pixel_origin: str = "center",
                length_unit: str = "mm", strain_convention=None, ignore_strain: bool = False) -> ToolResult:
    """Read one result file in ``fmt`` (one of :data:`READERS`).

    ``strain_convention`` (:class:`workbench.readers.conventions.StrainConvention`) states what a file's strain
    columns are where the file does not (a file with strain and no stated convention is refused, unless
    ``ignore_strain``); ``pixel_origin``/``length_unit`` the tool's pixel convention and length unit.

    Rows whose displacement is NaN (or that the tool flags) are failed points: ``valid`` is False there. A file
    in which no row holds a finite position and displacement is refused (:class:`ResultFormatError`): there is
    nothing to score, and a tool that failed everywhere should not look like one that measured zero points.
    """
    result = _read_any(path, fmt, columns, pixel_origin, length_unit, strain_convention, ignore_strain)
    usable = result.valid & np.isfinite(result.x_px) & np.isfinite(result.y_px)
    if not usable.any():
        what = "u, v" if result.has_2d else "U, V, W"
        raise ResultFormatError(f"{result.source}: no row holds a finite position and displacement ({what}); all "
                                f"{result.x_px.size} rows are NaN or flagged as failed")
    return result


#: What each layout ``auto`` recognises must have in its header (for the message naming what a file lacks).
LAYOUT_COLUMNS = {"native": ("x", "y", "u, v or U, V, W", "status_name"),
                  "dice": ("COORDINATE_X", "COORDINATE_Y", "DISPLACEMENT_X", "DISPLACEMENT_Y"),
                  "vic3d": ("x", "y", "sigma", "u, v or U, V, W"),
                  "matchid": ("Coordinates.Image X [Pixel] or x_pic", "Coordinates.Image Y [Pixel] or y_pic",
                              "disp.* displacements"),
                  "opencorr": ("x", "y", "u", "v", "ZNCC (or r1r2 ZNCC, r1t1 ZNCC, r1t2 ZNCC, tar_x..z)"),
                  "pyvale": ("subset_x", "subset_y", "disp_u", "disp_v", "converged")}


def _recognised(header: list[str]) -> list[str]:
    from workbench.peers.pyvale_engine import REQUIRED_COLUMNS as PYVALE
    from workbench.readers import matchid, opencorr, vic3d

    upper = [h.upper() for h in header]
    found = []
    if "status_name" in header and "x" in header and ("u" in header or "U" in header):
        found.append("native")
    if all(c in upper for c in ("COORDINATE_X", "COORDINATE_Y", "DISPLACEMENT_X", "DISPLACEMENT_Y")):
        found.append("dice")
    if vic3d.recognises(header):
        found.append("vic3d")
    if matchid.recognises(header):
        found.append("matchid")
    if opencorr.recognises(header):
        found.append("opencorr")
    if all(c in header for c in PYVALE):
        found.append("pyvale")
    return found


def read_results(path: str | Path, fmt: str = "auto", **options) -> list[ToolResult]:
    """Every result a file holds: one per deformed state for the formats of :data:`MULTI_STATE` (each with its
    ``state``), else the one :func:`read_result` reads. ``options`` as :func:`read_result`'s."""
    path = Path(path)
    if fmt == "auto" and path.is_file():
        fmt = detect_format(path)
    if fmt in MULTI_STATE:
        if not path.is_file():
            raise ValueError(f"result file not found: {path}")
        from workbench.readers.matlab import read_multidic, read_ncorr

        results = (read_ncorr if fmt == "ncorr" else read_multidic)(path)
        empty = [r.state for r in results if not (r.valid & np.isfinite(r.x_px) & np.isfinite(r.y_px)).any()]
        if empty:
            raise ResultFormatError(f"{path}: state {empty[0]} holds no finite position and displacement")
        return results
    return [read_result(path, fmt, **options)]


def detect_format(path: Path) -> str:
    """The layout of a result file, recognised from its header (:data:`LAYOUT_COLUMNS`).

    Raises
    ------
    ResultFormatError
        No layout or more than one matches: the message names the file's columns and, for each layout, what it
        lacks; ``--format csv --columns ...`` reads any other table.
    """
    from workbench.readers.matlab import recognises as matlab_layout

    mat = matlab_layout(Path(path))
    if mat is not None:
        return mat
    header, _ = read_table(path)
    found = _recognised(header)
    if len(found) == 1:
        return found[0]
    if len(found) > 1:
        raise ResultFormatError(f"{path}: its columns fit several layouts ({', '.join(found)}); give --format")
    lacks = "; ".join(f"{name}: {', '.join(cols)}" for name, cols in LAYOUT_COLUMNS.items())
    raise ResultFormatError(f"{path}: its columns ({', '.join(header[:20])}{' ...' if len(header) > 20 else ''}) match "
                            f"no known layout. The layouts need — {lacks}. Give --format with --columns "
                            "x=..,y=..,u=..,v=.. (--format csv) for any other table")


def _read_any(path, fmt: str, columns: str | None, pixel_origin: str, length_unit: str, strain_convention=None,
              ignore_strain: bool = False) -> ToolResult:
    path = Path(path)
    if fmt not in READERS:
        raise ValueError(f"--format {fmt!r}: choose one of {', '.join(READERS)}")
    if not path.is_file():
        raise ValueError(f"result file not found: {path}")
    if fmt != "csv" and columns:
        raise ValueError(f"--columns is for --format csv, not {fmt}")
    if pixel_origin not in PIXEL_ORIGINS:
        raise ValueError(f"--pixel-origin {pixel_origin!r}: choose one of {', '.join(PIXEL_ORIGINS)}")
    if length_unit not in LENGTH_UNITS_MM:
        raise ValueError(f"--length-unit {length_unit!r}: choose one of {', '.join(LENGTH_UNITS_MM)}")
    if fmt == "auto":
        fmt = detect_format(path)
    if fmt in MULTI_STATE:
        raise ValueError(f"{path}: a {fmt} file holds every state; read it with read_results")
    if fmt == "csv":
        if not columns:
            raise ValueError("--format csv needs --columns x=..,y=..,u=..,v=.. (or U=..,V=..,W=..)")
        return read_mapped_csv(path, parse_columns(columns), pixel_origin, length_unit, strain_convention,
                               ignore_strain)
    options = dict(strain_convention=strain_convention, ignore_strain=ignore_strain,
                   pixel_shift=PIXEL_ORIGINS[pixel_origin])
    if fmt == "vic3d":
        from workbench.readers.vic3d import read_vic
        return read_vic(path, length_scale_mm=LENGTH_UNITS_MM[length_unit], **options)
    if fmt == "matchid":
        from workbench.readers.matchid import read_matchid
        return read_matchid(path, **options)
    if fmt == "opencorr":
        from workbench.readers.opencorr import read_opencorr
        return read_opencorr(path, length_scale_mm=LENGTH_UNITS_MM[length_unit], **options)
    return {"native": read_native, "dice": read_dice, "pyvale": read_pyvale}[fmt](path)


#: Formats whose result files are named after the image pair with the camera's index last: VIC-3D's
#: ``dataset-0002_0.csv``, MatchID's ``Image_0007_0.tiff.csv`` (state 2 and 7, camera 0).
CAMERA_SUFFIXED = ("vic3d", "matchid")


def state_of(path: Path, fmt: str | None = None) -> int | None:
    """The state number a file name ends with (``DICe_solution_03.txt`` -> 3), or None; for the formats of
    :data:`CAMERA_SUFFIXED` the number before the camera suffix (``dataset-0002_0.csv`` -> 2)."""
    name = re.sub(r"(\.(tiff?|png|bmp|jpe?g))+$", "", Path(path).stem, flags=re.IGNORECASE)
    if fmt in CAMERA_SUFFIXED:
        m = re.search(r"(\d+)_\d\D*$", name)
        if m:
            return int(m.group(1))
    m = re.search(r"(\d+)\D*$", name)
    return int(m.group(1)) if m else None


def pixels_sha256(image: np.ndarray) -> str:
    """A hash of an image's grey levels (shape and values, whatever the file's dtype or format).

    Two files hold the same image when their hashes agree: a PNG and the TIFF an export re-encoded it to do, so a
    result can be matched to a dataset's state by what it measured, not by where the files lie.
    """
    image = np.ascontiguousarray(np.asarray(image, dtype=np.float64))
    digest = hashlib.sha256(repr(image.shape).encode())
    digest.update(image.tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class MeasuredImages:
    """The images a result file says it measured: its reference pair and the pair of its state.

    ``reference``/``state``: ``{"left": path, "right": path}`` as the tool recorded them; ``*_sha256``: the
    same keys, :func:`pixels_sha256` of each image; ``record``: the file that says so.
    """

    reference: dict
    state: dict
    reference_sha256: dict
    state_sha256: dict
    record: Path


def measured_images(path: str | Path) -> MeasuredImages | None:
    """What images ``path`` measured, from the ``workbench stereo`` manifest beside it; None where no record says.

    ``workbench stereo`` lists, in its folder's ``manifest.json``, every result file with the left and right images
    it measured and their pixel hashes (the reference's too), so a state is identified by its images whatever the
    file is called. A stereo manifest that predates those records is refused: its file names counted the states
    from the first deformed image (``state_000.csv`` was state 1), so its names cannot be trusted either.
    """
    from workbench.manifest import DatasetFolderError, read_manifest

    path = Path(path)
    try:
        manifest = read_manifest(path.parent)
    except DatasetFolderError:
        return None
    if manifest is None or manifest["kind"] != "stereo" or path.name not in manifest["files"]:
        return None
    record = path.parent / "manifest.json"
    entries = manifest.get("settings", {}).get("images")
    if entries is None:
        raise ResultFormatError(f"{path}: its {record} is from a `workbench stereo` older than the image records (its "
                                "state_NNN files were numbered from the first deformed image); give --state, or "
                                "run `workbench stereo` again")
    try:
        by_file = {e["file"]: e for e in entries}
        reference = next(e for e in entries if e["state"] == 0)
        entry = by_file.get(path.name)
        if entry is None:
            return None                  # a file of the folder that is no state result (the VTK's CSV twin, ...)
        return MeasuredImages({s: reference[s] for s in ("left", "right")}, {s: entry[s] for s in ("left", "right")},
                              {s: reference[f"{s}_pixels_sha256"] for s in ("left", "right")},
                              {s: entry[f"{s}_pixels_sha256"] for s in ("left", "right")}, record)
    except (KeyError, TypeError, StopIteration) as err:
        raise ResultFormatError(f"{record}: 'settings.images' is malformed ({type(err).__name__}: {err}); run "
                                "`workbench stereo` again") from None
