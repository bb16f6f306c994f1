"""Real images: Stereo-DIC Challenge 1.0 Sample 3 (DICe regression test ``stereo_d_spec``), ours vs DICe's gold.

Fetches nothing. Give it either DICe's bare git directory (``.../dicengine+dice/repo``; the files are taken
from ``HEAD:tests/regression/stereo_d_spec``) or a folder already holding that test's files (``cal.xml``,
``input.xml``, ``images/GT4-000N_{0,1}.tif``, ``gold/DICe_solution.e``). It copies them into a temporary folder,
runs ``python -m workbench.cli stereo`` with DICe's grid (subset 25 px, step 100 px, DICe's points
x = 124..1724, y = 24..924), reads DICe's gold Exodus file (the gold ``DICe_solution_N.txt`` files hold no 3-D
columns: the 3-D gold is only in ``DICe_solution.e``), and prints per frame the number of common points and the
mean / RMS difference (ours - DICe) of the 3-D displacement and of the reference 3-D positions, in um.

DICe's test folder holds ``best_fit_plane.dat``, so DICe's MODEL_* fields are in its best-fit-plane frame, not
camera 0's: ours (left camera frame) is aligned to it by ONE rigid fit (:func:`workbench.scoring.metrics.rigid_fit`) of
the reference positions of the common points; the same rotation is applied to our displacements.

    python benchmarks/real_sample3.py /work/.mirror/dicengine+dice/repo [--order 1] [--png W_diff.png]
"""
from __future__ import annotations

import argparse
import io
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TEST = "tests/regression/stereo_d_spec"
ROI = "124,24,1725,925"          # DICe's points: x 124..1724, y 24..924 every 100 px (x0 <= x < x1)
SUBSET, STEP = 25, 100           # input.xml: subset_size 25, step_size 100
MATCH_PX = 0.5


def extract(source: Path, dest: Path) -> str:
    """Copy the test's files from a bare git dir or a folder into ``dest``; returns a description of the source."""
    if (source / "HEAD").is_file() and (source / "objects").is_dir():
        git = ["git", f"--git-dir={source}"]
        commit = subprocess.run(git + ["rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
        names = subprocess.run(git + ["ls-tree", "-r", "HEAD", "--name-only", "--", TEST], check=True,
                               capture_output=True, text=True).stdout.split()
        for name in names:
            rel = Path(name).relative_to(TEST)
            if rel.suffix == ".txt" and rel.parent.name == "gold":
                continue                                     # the 2-D gold text is not needed
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            (dest / rel).write_bytes(subprocess.run(git + ["show", f"HEAD:{name}"], check=True,
                                                    capture_output=True).stdout)
        return f"git {source} commit {commit}:{TEST}"
    for name in ("cal.xml", "input.xml", "gold/DICe_solution.e"):
        if not (source / name).is_file():
            raise SystemExit(f"{source}: no {name} (give DICe's git dir or the stereo_d_spec folder)")
    shutil.copytree(source, dest, dirs_exist_ok=True)
    return f"folder {source}"


def read_exodus_gold(path: Path, out: Path) -> list[Path]:
    """DICe's Exodus gold -> one DICe-style solution text per frame (read back with read_result(.., 'dice'))."""
    from scipy.io import netcdf_file

    with netcdf_file(path, "r", mmap=False) as f:
        names = [b"".join(r).decode().strip("\x00 ") for r in f.variables["name_nod_var"].data]
        val = lambda n: np.array(f.variables[f"vals_nod_var{names.index(n) + 1}"].data, float)  # noqa: E731
        cols = ["COORDINATE_X", "COORDINATE_Y", "DISPLACEMENT_X", "DISPLACEMENT_Y", "SIGMA",
                "MODEL_COORDINATES_X", "MODEL_COORDINATES_Y", "MODEL_COORDINATES_Z",
                "MODEL_DISPLACEMENT_X", "MODEL_DISPLACEMENT_Y", "MODEL_DISPLACEMENT_Z"]
        data = {c: val(c) for c in cols}                                # (frames, points)
    files = []
    for t in range(data["SIGMA"].shape[0]):
        p = out / f"DICe_gold_{t}.txt"
        lines = ["SUBSET_ID," + ",".join(cols)]
        lines += [f"{i}," + ",".join(f"{data[c][t, i]:.9e}" for c in cols) for i in range(data["SIGMA"].shape[1])]
        p.write_text("\n".join(lines) + "\n")
        files.append(p)
    return files


def match(ax, ay, bx, by):
    """Indices (ia, ib) of a's and b's points within MATCH_PX of each other (nearest)."""
    d = np.hypot(ax[:, None] - bx[None, :], ay[:, None] - by[None, :])
    ib = d.argmin(1)
    ia = np.flatnonzero(d[np.arange(ax.size), ib] <= MATCH_PX)
    return ia, ib[ia]


def stats_um(d):
    """(N, 3) mm differences -> mean per axis, RMS per axis, RMS of the vector, um."""
    d = d * 1e3
    return d.mean(0), np.sqrt((d ** 2).mean(0)), float(np.sqrt((d ** 2).sum(1).mean()))


def flatness_um(X_mm: np.ndarray) -> tuple[float, float]:
    """RMS and largest distance (um) of (N, 3) points from their least-squares plane (SVD)."""
    X = X_mm[np.all(np.isfinite(X_mm), axis=1)]
    c = X.mean(axis=0)
    normal = np.linalg.svd(X - c, full_matrices=False)[2][-1]
    d = (X - c) @ normal * 1e3
    return float(np.sqrt(np.mean(d ** 2))), float(np.max(np.abs(d)))


def run_stereo(work: Path, calib: str, out: str, last: str, order: int) -> tuple[list[str], int]:
    cmd = [sys.executable, "-m", "workbench.cli", "stereo", "--calib", calib,
           "--left-ref", "images/GT4-0000_0.tif", "--right-ref", "images/GT4-0000_1.tif",
           "--left", f"images/GT4-000[1-{last[-1]}]_0.tif", "--right", f"images/GT4-000[1-{last[-1]}]_1.tif",
           "--roi", ROI, "--subset", str(SUBSET), "--step", str(STEP), "--order", str(order),
           "--out", out, "--overwrite"]
    print("run (in the work folder):", " ".join(c if "[" not in c else f"'{c}'" for c in cmd[1:]))
    r = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
    return (r.stdout + r.stderr).splitlines(), r.returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path, help="DICe's bare git dir, or a folder with the stereo_d_spec files")
    ap.add_argument("--order", type=int, choices=(1, 2), default=1,
                    help="our subset shape function (DICe's params: translation + normal strain; 1 is closest)")
    ap.add_argument("--keep", type=Path, default=None, help="work here (kept) instead of a temporary folder")
    ap.add_argument("--png", type=Path, default=None, help="write a map of the W (out-of-plane) difference, last frame")
    ap.add_argument("--compare-k3", action="store_true",
                    help="also measure the reference with k3 dropped from the calibration (flatness with and without)")
    args = ap.parse_args(argv)

    from measurement.calibration.formats import load_any_calibration
    from workbench.results import read_result
    from workbench.scoring.metrics import rigid_fit

    tmp = None
    if args.keep is None:
        tmp = tempfile.TemporaryDirectory(prefix="real_sample3_")
        work = Path(tmp.name)
    else:
        work = args.keep
        work.mkdir(parents=True, exist_ok=True)
    try:
        print("source:", extract(args.source, work))
        rig = load_any_calibration(work / "cal.xml")
        for side, cam in (("camera 0 = left", rig.left), ("camera 1 = right", rig.right)):
            print(f"{side}: {cam}")
        print(f"|T| = {np.linalg.norm(rig.T_right_from_left_mm):.4f} mm, T = {rig.T_right_from_left_mm}")

        frames = sorted((work / "images").glob("GT4-*_0.tif"))
        last = frames[-1].name[4:8]
        out = work / f"ours_order{args.order}"
        log, returncode = run_stereo(work, "cal.xml", out.name, last, args.order)
        print("\n".join(line for line in log if line.strip() and not line.startswith("stereo states")))
        if returncode != 0:
            print(f"workbench stereo exited {returncode}")
            if not (out / "reference.csv").is_file():
                return 1

        gold = read_exodus_gold(work / "gold" / "DICe_solution.e", work)
        ours_ref = read_result(out / "reference.csv")
        dref = read_result(gold[0], "dice")
        dref_X = dref.X_mm - dref.U_mm                       # MODEL_COORDINATES (reference positions)
        ia, ib = match(ours_ref.x_px, ours_ref.y_px, dref.x_px, dref.y_px)
        ok = ours_ref.valid[ia] & dref.valid[ib] & np.all(np.isfinite(ours_ref.X_mm[ia]), 1)
        ia, ib = ia[ok], ib[ok]
        print(f"\npoints: ours {ours_ref.valid.sum()}/{ours_ref.x_px.size} valid, DICe {dref.valid.sum()}/"
              f"{dref.x_px.size} valid, common {ia.size}")
        ja, jb = match(ours_ref.x_px, ours_ref.y_px, dref.x_px, dref.y_px)
        in_roi = dref.valid[jb]
        print(f"DICe's ROI (the points DICe measures): {in_roi.sum()}; ours measures "
              f"{int(ours_ref.valid[ja][in_roi].sum())} of them "
              f"({100.0 * ours_ref.valid[ja][in_roi].mean():.1f} %)")
        rms, worst = flatness_um(ours_ref.X_mm[ours_ref.valid])
        print(f"flatness of our reference points (plane fit, {int(ours_ref.valid.sum())} points): RMS {rms:.2f} um, "
              f"max {worst:.2f} um (k3 kept, as the VIC-3D calibration has it)")
        if args.compare_k3:
            from dataclasses import replace

            from measurement.calibration.io import CalibratedRig, save_rig

            no_k3 = CalibratedRig(rig.model, replace(rig.left, k3=0.0), replace(rig.right, k3=0.0),
                                  rig.R_right_from_left, rig.T_right_from_left_mm)
            save_rig(no_k3, work / "cal_no_k3.json")
            log2, rc2 = run_stereo(work, "cal_no_k3.json", "ours_no_k3", "0001", args.order)
            ref2 = read_result(work / "ours_no_k3" / "reference.csv")
            rms2, worst2 = flatness_um(ref2.X_mm[ref2.valid])
            print(f"flatness with k3 dropped (both cameras, everything else as the file): RMS {rms2:.2f} um, "
                  f"max {worst2:.2f} um ({int(ref2.valid.sum())} points; stereo exit {rc2})")
        A, B = ours_ref.X_mm[ia], dref_X[ib]
        R, t = rigid_fit(A, B)
        res = A @ R.T + t - B
        ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
        m, s, v = stats_um(res)
        print(f"frame: DICe's MODEL_* are in its best-fit-plane frame (best_fit_plane.dat); one rigid fit of our "
              f"reference positions onto DICe's: rotation {ang:.3f} deg, |t| {np.linalg.norm(t):.3f} mm")
        print(f"reference positions after the fit (ours - DICe), um: mean {np.round(m, 3)}, RMS {np.round(s, 3)}, "
              f"vector RMS {v:.3f}")
        print(f"DICe reference Z spread (plane frame): RMS {np.sqrt(np.mean(B[:, 2] ** 2)) * 1e3:.1f} um")

        print("\nframe  common  mean dU,dV,dW (um)           RMS dU,dV,dW (um)          RMS |dU| (um)  "
              "DICe mean U,V,W (um)")
        rows, last_map = [], None
        for k in range(1, len(gold)):
            f_ours = out / f"state_{k - 1:03d}.csv"
            if not f_ours.is_file():
                print(f"{k:5d}  ours missing (state skipped)")
                continue
            o, d = read_result(f_ours), read_result(gold[k], "dice")
            ja, jb = match(o.x_px, o.y_px, d.x_px, d.y_px)
            ok = o.valid[ja] & d.valid[jb] & np.all(np.isfinite(o.U_mm[ja]), 1) & np.all(np.isfinite(d.U_mm[jb]), 1)
            ja, jb = ja[ok], jb[ok]
            diff = o.U_mm[ja] @ R.T - d.U_mm[jb]
            m, s, v = stats_um(diff)
            dm = d.U_mm[jb].mean(0) * 1e3
            print(f"{k:5d}  {ja.size:6d}  {m[0]:7.3f} {m[1]:7.3f} {m[2]:7.3f}     {s[0]:7.3f} {s[1]:7.3f} {s[2]:7.3f}"
                  f"      {v:7.3f}      {dm[0]:7.2f} {dm[1]:7.2f} {dm[2]:7.2f}")
            worst = int(np.argmax(np.linalg.norm(diff, axis=1)))
            print(f"       largest |dU| {np.linalg.norm(diff[worst]) * 1e3:.2f} um at x,y = {o.x_px[ja][worst]:.0f},"
                  f"{o.y_px[ja][worst]:.0f} px")
            rows.append((k, ja.size, m, s, v, dm))
            last_map = (o.x_px[ja], o.y_px[ja], diff[:, 2] * 1e3, k)
        if args.png is not None and last_map is not None:
            import matplotlib
            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            from labio.atomic import atomic_write_bytes

            x, y, dw, k = last_map
            fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=100)
            lim = max(float(np.percentile(np.abs(dw), 95)), 1e-3)      # colour scale: 95th percentile
            sc = ax.scatter(x, y, c=np.clip(dw, -lim, lim), cmap="RdBu_r", vmin=-lim, vmax=lim, s=90, marker="s")
            ax.set_xlim(0, 1920)
            ax.set_ylim(1200, 0)
            ax.set_aspect("equal")
            ax.set_xlabel("x (px, left reference)")
            ax.set_ylabel("y (px)")
            ax.set_title(f"Sample 3 frame {k}: W ours - DICe (um, DICe plane frame; clipped at +-{lim:.1f})",
                         fontsize=9)
            fig.colorbar(sc, ax=ax, shrink=0.8, label="dW (um)")
            buf = io.BytesIO()
            fig.savefig(buf, format="png", bbox_inches="tight")
            plt.close(fig)
            atomic_write_bytes(args.png, buf.getvalue())
            print(f"wrote {args.png} ({len(buf.getvalue()) // 1024} KB)")
        return 0
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":
    raise SystemExit(main())
