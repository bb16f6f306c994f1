"""Ncorr and MultiDIC results: MATLAB v7.3 ``.mat`` files (HDF5), one file holding every state, read into one
:class:`workbench.results.ToolResult` per deformed state.

MATLAB v7.3 files are HDF5 (``h5py``): a struct is a group, a cell array or a struct array's field a dataset of
object references, every numeric array stored transposed (MATLAB is column-major), text as UTF-16 code units.

**Ncorr** (``ncorr.m`` saves ``reference_save``, ``current_save``, ``data_dic_save`` with ``-v7.3``):
``data_dic_save.displacements(k)`` for deformed image k: ``plot_u_ref_formatted``, ``plot_v_ref_formatted``
(the displacement on the reference's reduced grid, in ``dispinfo.units`` = px times ``dispinfo.pixtounits``; grid
element (i, j), 1-based, is the reference pixel ((j - 1)(s + 1) + 1, (i - 1)(s + 1) + 1), 1-based, with
``s = dispinfo.spacing``); ``data_dic_save.strains(k).plot_exx_ref_formatted`` ... (Green-Lagrange, tensor shear:
Ncorr's ``_ref`` strains). Points outside the ROI hold 0 in both u and v (the ROI itself is an object MATLAB alone
reads): a point whose u and v are both exactly 0 is taken as outside (a real match is never exactly 0.0 in both).
Evidence: justinblaber/ncorr_2D_matlab 525ef43 (BSD): ``ncorr.m`` (the save call, the formatted plots, the strain).

**MultiDIC** (``MultiDIC/MultiDIC``, Apache-2.0), saved with ``-v7.3``:

* ``DIC2DpairResults_C_<a>_C_<b>.mat`` (STEP2): ``DIC2DpairResults`` with ``nImages``, ``nCamRef``, ``nCamDef``,
  ``Points`` (a cell of 2 x nImages arrays of n x 2 pixel positions, 1-based: first camera ``nCamRef``'s images
  1..nImages, then camera ``nCamDef``'s; NaN where not correlated), ``CorCoeffVec``: read as a 2-D result of the
  reference camera (u, v = Points{k+1} - Points{1}, px);
* ``DIC3Dcombined_<N>Pairs.mat`` (STEP3): ``DIC3Dcombined`` with ``Points3D`` (a cell of n x 3 positions per
  image, in the calibration object's frame: score with ``--align rigid``) and ``AllPairsResults`` (the pairs'
  DIC2DpairResults, whose first pair's ``Points{1}`` gives each point's pixel in the reference camera's first image).
  MultiDIC's strains are per triangle face (STEP4), not per point, and are not read.

Evidence: the committed sample ``sample_data/speckledObjectImages/DIC2DpairResults_C_201_C_202.mat`` (its layout;
an excerpt is in tests/data/tool_results) and ``lib_MultiDIC`` (the STEP3 combination).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: MATLAB v7.3 files start with this text (their HDF5 user block).
MAT73_SIGNATURE = b"MATLAB 7.3 MAT-file"


def _open(path: Path):
    from workbench.readers.table import ResultFormatError

    with open(path, "rb") as handle:
        head = handle.read(128)
    if not head.startswith(MAT73_SIGNATURE):
        if head.startswith(b"MATLAB 5.0 MAT-file"):
            raise ResultFormatError(f"{path}: a MATLAB v5 file; Ncorr and MultiDIC save v7.3 (HDF5): save it again "
                                    "with save(..., '-v7.3')")
        raise ResultFormatError(f"{path}: not a MATLAB v7.3 .mat file")
    import h5py

    return h5py.File(path, "r")


def _array(f, ref) -> np.ndarray:
    """A referenced MATLAB array, in MATLAB's (row, column) order."""
    return np.array(f[ref]).T


def _scalar(node) -> float:
    return float(np.array(node).ravel()[0])


def _cell(f, dataset) -> list[np.ndarray]:
    """A MATLAB cell (or struct-array field) dataset of references -> its arrays, in MATLAB's linear order."""
    refs = np.array(dataset).T.ravel(order="F")
    return [_array(f, r) for r in refs]


def _field(path: Path, group, name: str, what: str):
    from workbench.readers.table import ResultFormatError

    if name not in group:
        raise ResultFormatError(f"{path}: {what} has no field {name!r} (it has {', '.join(sorted(group.keys()))})")
    return group[name]


def recognises(path: Path) -> str | None:
    """``"ncorr"`` or ``"multidic"`` for a v7.3 file holding their variables, else None."""
    try:
        with open(path, "rb") as handle:
            if not handle.read(len(MAT73_SIGNATURE)) == MAT73_SIGNATURE:
                return None
        import h5py

        with h5py.File(path, "r") as f:
            if "data_dic_save" in f:
                return "ncorr"
            if "DIC2DpairResults" in f or "DIC3Dcombined" in f:
                return "multidic"
    except OSError:
        return None
    return None


def read_ncorr(path: Path) -> list:
    """Every deformed state of an Ncorr ``.mat`` (module notes): 2-D ToolResults, state k = displacements(k)."""
    from workbench.readers.table import ResultFormatError, ToolResult

    with _open(path) as f:
        if "data_dic_save" not in f:
            raise ResultFormatError(f"{path}: no data_dic_save (an Ncorr file saves reference_save, current_save, "
                                    f"data_dic_save); it holds {', '.join(sorted(f.keys()))}")
        data = f["data_dic_save"]
        info = _field(path, data, "dispinfo", "data_dic_save")
        spacing = int(round(_scalar(_field(path, info, "spacing", "data_dic_save.dispinfo"))))
        to_units = _scalar(info["pixtounits"]) if "pixtounits" in info else 1.0
        disp = _field(path, data, "displacements", "data_dic_save")
        us = _cell(f, _field(path, disp, "plot_u_ref_formatted", "data_dic_save.displacements"))
        vs = _cell(f, _field(path, disp, "plot_v_ref_formatted", "data_dic_save.displacements"))
        strains = None
        if "strains" in data and all(k in data["strains"] for k in ("plot_exx_ref_formatted", "plot_eyy_ref_formatted",
                                                                   "plot_exy_ref_formatted")):
            strains = [_cell(f, data["strains"][k]) for k in ("plot_exx_ref_formatted", "plot_eyy_ref_formatted",
                                                             "plot_exy_ref_formatted")]
    out = []
    for k, (u, v) in enumerate(zip(us, vs)):
        rows, cols = np.indices(u.shape)
        x, y = (cols * (spacing + 1)).ravel().astype(float), (rows * (spacing + 1)).ravel().astype(float)
        u_px, v_px = u.ravel() / to_units, v.ravel() / to_units
        valid = np.isfinite(u_px) & np.isfinite(v_px) & ~((u_px == 0.0) & (v_px == 0.0))
        strain = None
        if strains is not None and len(strains[0]) > k:
            strain = np.column_stack([strains[c][k].ravel() for c in range(3)])
            if strain.shape[0] != x.size:
                strain = None                  # a strain grid of another shape (its own radius): not read
            else:
                strain[~valid] = np.nan
        out.append(ToolResult(path, "Ncorr", x, y, valid, np.where(valid, u_px, np.nan), np.where(valid, v_px, np.nan),
                              strain=strain, state=k + 1))
    return out


def _pair_points(path, f, pair) -> tuple[int, list[np.ndarray]]:
    n = int(round(_scalar(_field(path, pair, "nImages", "DIC2DpairResults"))))
    points = _cell(f, _field(path, pair, "Points", "DIC2DpairResults"))
    if len(points) != 2 * n:
        from workbench.readers.table import ResultFormatError
        raise ResultFormatError(f"{path}: DIC2DpairResults.Points holds {len(points)} arrays, not 2 x nImages = "
                                f"{2 * n}")
    return n, points


def read_multidic(path: Path) -> list:
    """Every deformed state of a MultiDIC ``.mat`` (module notes): 2-D ToolResults from a DIC2DpairResults file, 3-D
    from a DIC3Dcombined file; state k = image k + 1."""
    from workbench.readers.table import ResultFormatError, ToolResult

    with _open(path) as f:
        if "DIC2DpairResults" in f:
            n, points = _pair_points(path, f, f["DIC2DpairResults"])
            ref = points[0]
            x, y = ref[:, 0] - 1.0, ref[:, 1] - 1.0                 # MATLAB's 1-based pixel centres
            out = []
            for k in range(1, n):
                d = points[k] - ref
                valid = np.all(np.isfinite(d), axis=1) & np.all(np.isfinite(ref), axis=1)
                d[~valid] = np.nan
                out.append(ToolResult(path, "MultiDIC (2-D pair)", x, y, valid, d[:, 0], d[:, 1], state=k))
            return out
        if "DIC3Dcombined" in f:
            combined = f["DIC3Dcombined"]
            P = _cell(f, _field(path, combined, "Points3D", "DIC3Dcombined"))
            pairs = np.array(_field(path, combined, "AllPairsResults", "DIC3Dcombined")).T.ravel(order="F")
            if not len(pairs):
                raise ResultFormatError(f"{path}: DIC3Dcombined.AllPairsResults is empty: no pixel positions")
            _, points = _pair_points(path, f, f[pairs[0]])
            ref = points[0]
            if ref.shape[0] != P[0].shape[0]:
                raise ResultFormatError(f"{path}: the first pair's {ref.shape[0]} points are not the {P[0].shape[0]} of "
                                        "Points3D (a combination of several pairs: give the pair's file)")
            x, y = ref[:, 0] - 1.0, ref[:, 1] - 1.0
            out = []
            for k in range(1, len(P)):
                U = P[k] - P[0]
                valid = np.all(np.isfinite(U), axis=1) & np.all(np.isfinite(P[0]), axis=1)
                X = np.where(valid[:, None], P[k], np.nan)
                out.append(ToolResult(path, "MultiDIC", x, y, valid, X_mm=X, U_mm=np.where(valid[:, None], U, np.nan),
                                      frame="MultiDIC's calibration-object frame (score with --align rigid)", state=k))
            return out
        raise ResultFormatError(f"{path}: no DIC2DpairResults or DIC3Dcombined (MultiDIC's STEP2 / STEP3 results); it "
                                f"holds {', '.join(sorted(f.keys()))}")
