"""Render speed beside a peer: our Mitsuba renderer and pyvale's rasteriser riley (``riley-raster``).

Measures, in one process on the same machine, the seconds to render one stereo pair (left and right camera
of ``paper_rig(scale)``, default full 2456 x 2058 px each) of the same speckled plate with

* ``ours``: :func:`scenes.rendering.mitsuba.render_view`, pinhole, the rig's tilted (Scheimpflug) sensors with their
  Brown distortion, ``--spp`` stratified-jittered Monte-Carlo samples per pixel (box pixel filter), bilinear
  texture lookup; one ``render_view`` call per camera;
* ``riley``: ``riley.raster`` (rasteriser, no ray tracing), both cameras in one call. Its per-pixel
  sampling is ``Camera.sub_sample = n``: a regular, deterministic n x n grid of sub-pixel centres averaged
  with a box filter (``PsfType.pixel_box``), so ``--spp`` must be a square (64 -> n = 8; otherwise the
  nearest square is used and the table says so). Texture lookup ``TextureSample.linear`` (bilinear, like
  ours). Riley's pinhole has its principal point at the image centre and no sensor tilt: each riley camera
  sits at our camera's centre and looks along the ray of our image centre (``roi_cent_world`` is where that
  ray meets the plate), with our fx, fy (as focal length and pixel size) and our k1, k2, p1, p2 as its
  Brown model (``distort_model=1``, centred on the image centre, so not the same field of view pixel for
  pixel: the same amount of work per pixel, not the same image).

Both get the same speckle texture (generated once with :class:`scenes.specimens.plate.SpeckledPlate`, float32
radiance in [0, 1]; riley copies it to float64 on every call) and the same two-triangle plate, which fills
both views. Riley's texel centres sit at ``u (cols - 1)``, ours at ``u cols - 1/2``: riley's uvs are
remapped so that each texel lands on the same spot of the plate. Both images are radiance times 255 grey.

Timing: one warm-up pair (JIT compilation, first allocation), then the best of ``--repeat`` pairs, with
``time.perf_counter``; each timed pair includes each renderer's scene set-up from the same numpy inputs.
Both use all ``os.cpu_count()`` threads (Dr.Jit's default pool; riley ``RasterConfig(parallel=...)``).
Throughput is ``width * height * spp * 2 / seconds / 1e6`` Msamples/s. Prints a table with the machine and
package versions and writes it to ``--out``.

    .venv-peers/bin/python benchmarks/render_peer_riley.py [--scale 1.0] [--spp 64] [--repeat 2]
        [--out reports/render_peer_riley/benchmark.txt]

Then, at equal *measured* render error (:func:`equal_error_comparison`): our deterministic renderer (no Monte
Carlo) against riley at the coarsest sub-pixel grid whose error against its own converged image is no larger.

``--check`` renders at scale 0.1 with 4 spp and prints the table only (a quick smoke run);
:func:`render_pair_both` is what the test calls.
"""
from __future__ import annotations

import argparse
import importlib.metadata
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from labio.atomic import atomic_write_text  # noqa: E402
from scenes.optics.backend import VARIANT
from scenes.rendering.mitsuba import render_view
from scenes.specimens.plate import SpeckledPlate
from scenes.optics.projection import pixel_rays
from workbench.experiments.calibration.views import camera_to_sensor_spec  # noqa: E402
from workbench.rigs import facing_plane_world, paper_rig  # noqa: E402

EXPOSURE_GREY = 255.0
#: riley's background radiance (what a sub-pixel that sees no surface gets): so negative that a pixel with even
#: one such sub-pixel of up to 32 x 32 comes out negative, which no texture in [0, 1] can produce.
RILEY_BACKGROUND = -1.0e6
SIDES = ("left", "right")


@dataclass
class PlateScene:
    """The stereo rig, one speckled plate filling both views, and both renderers' camera descriptions."""

    rig: object
    plate: SpeckledPlate
    texture: np.ndarray                  # (rows, cols) float32 radiance, shared by both renderers
    surface: object                      # our TexturedSurface
    specs: dict                          # side -> SensorSpec (ours)
    poses: dict                          # side -> (R_cam_from_world, t_cam_from_world_mm)
    riley_cameras: dict = field(default_factory=dict)   # side -> riley.Camera (without sub_sample set)

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of both images."""
        return self.rig.left.height, self.rig.left.width


def _plate_frame(normal_world: np.ndarray) -> np.ndarray:
    """R_world_from_plate: plate z along -normal (the painted -z face looks at the cameras), x near world x."""
    z = -np.asarray(normal_world, float) / np.linalg.norm(normal_world)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def _hit_plane(origins, directions, centre, normal) -> np.ndarray:
    s = ((centre - origins) @ normal) / (directions @ normal)
    return origins + s[:, None] * directions


def _border_pixels(width: int, height: int, n: int = 24) -> np.ndarray:
    """OpenCV pixel coordinates along the outer edge of the image (pixel centres at integers, -0.5 = edge)."""
    u = np.linspace(-0.5, width - 0.5, n)
    v = np.linspace(-0.5, height - 0.5, n)
    return np.concatenate([np.column_stack([u, np.full(n, -0.5)]), np.column_stack([u, np.full(n, height - 0.5)]),
                           np.column_stack([np.full(n, -0.5), v]), np.column_stack([np.full(n, width - 0.5), v])])


def _riley_pose(C: np.ndarray, forward: np.ndarray, x_hint: np.ndarray) -> tuple[float, float, float]:
    """riley's (alpha_z, beta_y, gamma_x) of a camera at C looking along ``forward`` (OpenCV x right, y down).

    riley's rotation is camera-to-world, ``Rz(alpha) Ry(beta) Rx(gamma)``, of an OpenGL camera (looking down
    its -z, y up), as pyvale's ``to_riley_camera`` hands it over (SciPy ``as_euler("xyz")`` reversed).
    """
    from scipy.spatial.transform import Rotation

    z = forward / np.linalg.norm(forward)
    x = x_hint - (x_hint @ z) * z
    x /= np.linalg.norm(x)
    R_cv_to_world = np.column_stack([x, np.cross(z, x), z])
    R_gl_to_world = R_cv_to_world @ np.diag([1.0, -1.0, -1.0])
    return tuple(float(a) for a in Rotation.from_matrix(R_gl_to_world).as_euler("xyz")[::-1])


def build_scene(scale: float, seed: int = 0) -> PlateScene:
    """The rig at ``scale``, the plate on its facing plane, big enough to fill both cameras' views (ours and
    riley's), its speckle texture generated once (2.5 texels and 1/5 speckle per pixel at the plate)."""
    import riley

    rig = paper_rig(scale)
    centre, normal = facing_plane_world(rig)
    R_wp = _plate_frame(normal)
    specs = {s: camera_to_sensor_spec(rig.camera(s), rig.pixel_pitch_mm) for s in SIDES}
    poses = {s: rig.pose(s) for s in SIDES}

    riley_cameras, extent_points = {}, []
    for s in SIDES:
        cam, (R, t) = rig.camera(s), poses[s]
        o, d = pixel_rays(specs[s], R, t, _border_pixels(cam.width, cam.height))
        extent_points.append(_hit_plane(o, d, centre, normal))
        # riley: centred pinhole along our image centre's ray; the ray meets the plate at roi_cent_world.
        o_c, d_c = pixel_rays(specs[s], R, t, np.array([[(cam.width - 1) / 2, (cam.height - 1) / 2]]))
        roi = _hit_plane(o_c, d_c, centre, normal)[0]
        C = o_c[0]
        focal_mm = cam.fx * rig.pixel_pitch_mm
        rcam = riley.Camera(
            pixels_num=(cam.width, cam.height),
            pixels_size=(rig.pixel_pitch_mm, focal_mm / cam.fy),
            pos_world=tuple(float(c) for c in C), rot_world=_riley_pose(C, d_c[0], R.T @ [1.0, 0.0, 0.0]),
            roi_cent_world=tuple(float(c) for c in roi), focal_length=focal_mm, sub_sample=1,
            distort_model=1, distort_k1=cam.k1, distort_k2=cam.k2, distort_p1=cam.p1, distort_p2=cam.p2)
        riley_cameras[s] = rcam
        # riley's own view: undistorted corner directions of a centred pinhole (distortion moves them < 1 %).
        z = d_c[0] / np.linalg.norm(d_c[0])
        x = R.T @ [1.0, 0.0, 0.0] - ((R.T @ [1.0, 0.0, 0.0]) @ z) * z
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        b = _border_pixels(cam.width, cam.height) + 0.5 - [cam.width / 2, cam.height / 2]
        dirs = z + (b[:, :1] / cam.fx) * x + (b[:, 1:] / cam.fy) * y
        extent_points.append(_hit_plane(np.repeat(C[None], len(dirs), 0), dirs, centre, normal))

    p = (np.concatenate(extent_points) - centre) @ R_wp          # plate coordinates (z ~ 0)
    lo, hi = p[:, :2].min(0), p[:, :2].max(0)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * 1.06              # 6 % margin
    px_mm = float(np.linalg.norm(centre)) / rig.left.fx
    plate = SpeckledPlate(width_mm=2 * half[0], height_mm=2 * half[1], texel_mm=px_mm / 2.5,
                          speckle_mm=5 * px_mm, seed=seed)
    texture = plate.texture()
    surface = plate.surface(R_wp, centre + R_wp @ [mid[0], mid[1], 0.0], texture)
    return PlateScene(rig, plate, texture, surface, specs, poses, riley_cameras)


def riley_sub_sample(spp: int) -> int:
    """riley's n (n x n sub-pixel grid) closest to ``spp`` samples per pixel."""
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    return max(1, int(round(math.sqrt(spp))))


def riley_mesh(scene: PlateScene):
    """Our plate as a riley tri3 mesh with a float texture shader (bilinear), texels on the same plate spots."""
    import riley

    s = scene.surface
    rows, cols = s.texture.shape
    # ours: texel centre c at u = (c + 1/2) / cols; riley: at u = c / (cols - 1).
    uv = np.column_stack([(s.uv[:, 0] * cols - 0.5) / (cols - 1), (s.uv[:, 1] * rows - 0.5) / (rows - 1)])
    shader = riley.TextureShader(uvs=uv, texture=s.texture[None], sample=riley.TextureSample.linear,
                                 scaling_type=riley.ScaleStrategy.none)
    conv = riley.ConnectConvention(riley.EElemType.TRI3, riley.EConnectAxis.ROW, 0, riley.ENodeOrder.RILEY)
    # Same winding as ours: counter-clockwise seen from the painted side (riley culls the other side).
    return riley.create_mesh(conv, riley.MeshType.tri3, np.asarray(s.vertices_mm, float),
                             np.asarray(s.faces, np.int64), shader)


def render_ours(scene: PlateScene, spp: int, seed: int = 0) -> list[np.ndarray]:
    """Left and right image, (H, W) float32 grey, one render_view call each."""
    return [render_view(scene.specs[s], *scene.poses[s], [scene.surface], spp=spp, seed=seed + k,
                        exposure_grey=EXPOSURE_GREY).image_grey for k, s in enumerate(SIDES)]


def render_riley(scene: PlateScene, mesh, spp: int, threads: int | None = None) -> list[np.ndarray]:
    """Left and right image, (H, W) float grey, both cameras in one riley.raster call."""
    import dataclasses

    import riley

    n = riley_sub_sample(spp)
    cams = [dataclasses.replace(scene.riley_cameras[s], sub_sample=n) for s in SIDES]
    config = riley.RasterConfig(parallel=threads or os.cpu_count() or 1, save_strategy=riley.SaveStrategy.memory,
                                image_save_mode=riley.ImageSaveMode.grey, report=riley.ReportMode.off)
    config.background_value = RILEY_BACKGROUND
    out = riley.raster(mesh, cams, config)       # (cameras, frames, fields, rows, cols)
    if out is None or out.shape[0] != 2:
        raise RuntimeError(f"riley returned {None if out is None else out.shape}, expected 2 cameras")
    return [out[k, 0, 0] * EXPOSURE_GREY for k in range(2)]


def _best_of(fn, repeat: int) -> tuple[float, object]:
    result = fn(0)                               # warm-up (JIT, first allocations), not timed
    times = []
    for k in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn(k + 1)
        times.append(time.perf_counter() - t0)
    return min(times), result


def render_pair_both(scale: float = 1.0, spp: int = 64, repeat: int = 1, seed: int = 0,
                     mc_target_grey: float | None = None) -> dict:
    """Render the stereo pair with both renderers and time them.

    Returns ``{"scene": PlateScene, "rows": [row, ...]}``; each row has ``renderer``, ``width``, ``height``,
    ``spp`` (samples per pixel actually used), ``seconds`` (best of ``repeat`` pairs after a warm-up),
    ``msamples_per_s``, ``per_pixel`` (what the renderer does per pixel) and ``images`` ([left, right]).
    """
    scene = build_scene(scale, seed)
    mesh = riley_mesh(scene)
    h, w = scene.shape
    n = riley_sub_sample(spp)
    rows = []
    t_ours, img_ours = _best_of(lambda k: render_ours(scene, spp, seed=seed + 2 * k), repeat)
    rows.append(dict(renderer=f"ours (Mitsuba {VARIANT})", spp=spp, seconds=t_ours, images=img_ours,
                     per_pixel=f"{spp} stratified-jittered MC rays, box filter, bilinear texture"))
    if mc_target_grey is not None:
        from scenes.rendering.adaptive import AdaptiveSettings, render_views_adaptive

        def adaptive(k):
            return render_views_adaptive([(scene.specs[s], scene.poses[s]) for s in ("left", "right")],
                                         [scene.surface], seed=seed + 2 * k,
                                         settings=AdaptiveSettings(target_mc_grey=mc_target_grey))
        t_ad, res = _best_of(adaptive, repeat)
        traced = float(np.mean([r.mc["sensor_spp"] for r in res]))
        rows.append(dict(renderer="ours, adaptive (scenes.rendering.adaptive)", spp=traced, seconds=t_ad,
                         images=[r.image_grey for r in res],
                         per_pixel=f"adaptive stratified MC, target {mc_target_grey:g} grey RMS, measured "
                                   + " / ".join(f"{r.mc['mc_rms_grey']:.3f}" for r in res)
                                   + f" grey; spp = samples traced per sensor pixel, pilot and checks included"))
    t_riley, img_riley = _best_of(lambda k: render_riley(scene, mesh, spp), repeat)
    rows.append(dict(renderer="riley (rasteriser)", spp=n * n, seconds=t_riley, images=img_riley,
                     per_pixel=f"regular {n} x {n} sub-pixel grid, box average, bilinear texture"))
    for r in rows:
        r.update(width=w, height=h, msamples_per_s=w * h * r["spp"] * 2 / r["seconds"] / 1e6)
    return {"scene": scene, "rows": rows}


def equal_error_comparison(scale: float = 1.0, seed: int = 0, ref_spp: int = 2048, window: int = 300,
                           riley_ns=(1, 2, 3, 4, 6, 8), riley_ref_n: int = 24) -> dict:
    """Time per stereo pair at equal *measured* render error: our deterministic renderer
    (:func:`scenes.rendering.exact.render_view_exact`: exact coverage, Gauss-Legendre quadrature of the speckle)
    against riley at the coarsest sub-pixel grid whose error is no larger.

    Each renderer's error is measured against its own converged image of the same plate (the two model
    different cameras: ours the tilted sensor, riley a centred untilted pinhole): ours against the mean of two
    ``ref_spp``-spp Mitsuba renders over a ``window``-px square at the image centre, net of that reference's own
    Monte-Carlo noise; riley against its ``riley_ref_n`` x ``riley_ref_n`` grid render over the same window.
    Returns ``{"ours": {...}, "riley": [{n, seconds, error_grey: [left, right]}, ...], "equal": {...}}``.
    """
    from scenes.rendering.exact import render_view_exact

    scene = build_scene(scale, seed)
    mesh = riley_mesh(scene)
    h, w = scene.shape
    half = window // 2
    y0, x0 = max(0, h // 2 - half), max(0, w // 2 - half)
    win = (slice(y0, y0 + window), slice(x0, x0 + window))

    def ours_pair(_k):
        return [render_view_exact(scene.specs[s], *scene.poses[s], [scene.surface], exposure_grey=EXPOSURE_GREY)[0]
                for s in SIDES]

    t_ours, img_ours = _best_of(ours_pair, 2)
    ours_err = []
    for s, img in zip(SIDES, img_ours):
        a, b = (render_view(scene.specs[s], *scene.poses[s], [scene.surface], spp=ref_spp, seed=seed + 11 + k,
                            exposure_grey=EXPOSURE_GREY, crop=(x0, y0, window, window)).image_grey for k in (0, 1))
        ref, noise = 0.5 * (a + b), 0.5 * (a - b)
        e2 = float(np.mean((img[win] - ref) ** 2)) - float(np.mean(noise ** 2))
        ours_err.append(math.sqrt(max(e2, 0.0)))
    reference = render_riley(scene, mesh, riley_ref_n ** 2)
    riley_rows = []
    for n in riley_ns:
        t, imgs = _best_of(lambda k: render_riley(scene, mesh, n * n), 1)
        err = [float(np.sqrt(np.mean((img[win] - ref[win]) ** 2))) for img, ref in zip(imgs, reference)]
        riley_rows.append({"n": n, "seconds": t, "error_grey": err})
    target = max(ours_err)
    equal = next((r for r in riley_rows if max(r["error_grey"]) <= target), None)
    return {"scene": scene, "ours": {"seconds": t_ours, "error_grey": ours_err}, "riley": riley_rows,
            "equal": equal, "ref_spp": ref_spp, "riley_ref_n": riley_ref_n, "window": window, "shape": (h, w)}


def format_equal_error(result: dict) -> str:
    h, w = result["shape"]
    o = result["ours"]
    lines = ["", f"At equal measured render error ({w} x {h} px per camera; error = RMS over a {result['window']} px "
             "square at the image centre against each renderer's own converged image: ours vs 2 x "
             f"{result['ref_spp']} spp Mitsuba net of its MC noise, riley vs its {result['riley_ref_n']} x "
             f"{result['riley_ref_n']} grid):",
             f"{'renderer':44s} {'s / stereo pair':>16s} {'error left / right (grey)':>28s}",
             f"{'ours, deterministic (exact coverage + 6x6 GL)':44s} {o['seconds']:>16.3f} "
             f"{o['error_grey'][0]:>13.4f} / {o['error_grey'][1]:.4f}"]
    for r in result["riley"]:
        lines.append(f"{'riley, ' + str(r['n']) + ' x ' + str(r['n']) + ' grid':44s} {r['seconds']:>16.3f} "
                     f"{r['error_grey'][0]:>13.4f} / {r['error_grey'][1]:.4f}")
    e = result["equal"]
    if e is None:
        lines.append(f"no riley grid up to {result['riley'][-1]['n']} x {result['riley'][-1]['n']} reaches our error "
                     f"({max(o['error_grey']):.4f} grey): ours is faster than every riley time above at a lower error, "
                     f"at least {result['riley'][-1]['seconds'] / o['seconds']:.2f}x")
    else:
        lines.append(f"riley's coarsest grid at or below our error ({max(o['error_grey']):.4f} grey): {e['n']} x {e['n']}, "
                     f"{e['seconds']:.3f} s per pair; ours {o['seconds']:.3f} s: ours is "
                     f"{e['seconds'] / o['seconds']:.2f}x faster at equal error")
    return "\n".join(lines) + "\n"


def _version(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


def format_table(result: dict, spp_asked: int, repeat: int) -> str:
    scene = result["scene"]
    tex = scene.texture
    lines = [
        "Render speed, one stereo pair (left + right camera of paper_rig) of a speckled plate, pinhole",
        f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, "
        f"os.cpu_count() = {os.cpu_count()}, Python {platform.python_version()}",
        f"packages: mitsuba {_version('mitsuba')} ({VARIANT}), drjit {_version('drjit')}, "
        f"riley-raster {_version('riley-raster')}, pyvale {_version('pyvale')}, numpy {np.__version__}",
        f"texture: {tex.shape[1]} x {tex.shape[0]} texels (float32, mean radiance {float(tex.mean()):.4f}), "
        f"the same array for both; plate {scene.plate.width_mm:.1f} x {scene.plate.height_mm:.1f} mm",
        f"timing: best of {repeat} after one warm-up pair, time.perf_counter, spp asked {spp_asked}",
        "",
        f"{'renderer':34s} {'image size':>12s} {'spp':>5s} {'s / stereo pair':>16s} {'Msamples/s':>11s}",
    ]
    for r in result["rows"]:
        lines.append(f"{r['renderer']:34s} {r['width']:>5d} x {r['height']:<4d} {r['spp']:>5.4g} "
                     f"{r['seconds']:>16.3f} {r['msamples_per_s']:>11.1f}")
    lines.append("")
    for r in result["rows"]:
        lines.append(f"per pixel, {r['renderer']}: {r['per_pixel']}")
    lines.append("Msamples/s = width * height * spp * 2 / seconds / 1e6. ours: tilted sensor + Brown distortion, "
                 "principal point of Table 1; riley: centred untilted pinhole + the same Brown terms, aimed at "
                 "the same plate spot (the same work per pixel, not the same image).")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--mc-target-grey", type=float, default=0.3,
                    help="also time our adaptive renderer at this Monte-Carlo noise target (0: skip)")
    ap.add_argument("--out", default="reports/render_peer_riley/benchmark.txt")
    ap.add_argument("--check", action="store_true", help="quick smoke run: scale 0.1, 4 spp, 1 repeat, no file")
    ap.add_argument("--no-equal-error", action="store_true",
                    help="skip the comparison at equal measured render error (equal_error_comparison)")
    args = ap.parse_args(argv)
    if args.check:
        args.scale, args.spp, args.repeat = 0.1, 4, 1
    result = render_pair_both(args.scale, args.spp, args.repeat, mc_target_grey=args.mc_target_grey or None)
    table = format_table(result, args.spp, args.repeat)
    if not args.no_equal_error:
        table += format_equal_error(equal_error_comparison(args.scale, ref_spp=64 if args.check else 2048,
                                                           window=40 if args.check else 300))
    print(table, end="")
    if not args.check:
        out = Path(args.out)
        if not out.is_absolute():
            out = ROOT / out
        atomic_write_text(out, table)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
