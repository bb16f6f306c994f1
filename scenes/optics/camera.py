"""The Scheimpflug camera as a Mitsuba sensor plugin (truth side).

Written from the physical geometry of a tilted sensor, *not* from ``measurement.camera`` (DESIGN.md §1): the
two implementations must agree, and ``tests/test_render_agreement.py`` measures that they do.

Geometry, in the camera frame (OpenCV axes: x right, y down, z forward; lengths in units of the image
distance, i.e. the ideal image plane is z = 1 in front of the lens):

* the sensor is a plane through the principal point (0, 0, 1), tilted by rotating it about the camera X axis
  by alpha and then about the camera Y axis by beta (Mitsuba's own rotation transforms build this);
* a pixel (u, v) sits at ``(0,0,1) + (u - cx)/fx * e1 + (v - cy)/fy * e2`` with e1, e2 the tilted sensor
  axes (the physical sensor is the point mirror of this plane behind the lens);
* the lens distortion (Brown k1, k2, p1, p2 on the ideal plane, distortion applied *before* the tilt as in
  the paper; optionally OpenCV's k3 and thin-prism s1..s4, which the instrument does not model) is undone
  per ray by fixed-point iteration, giving the chief ray direction (x_n, y_n, 1);
* pinhole: the ray leaves the lens centre along the chief ray;
* thin lens: the sensor point at distance ``z_i`` behind the lens is conjugate (1/z_o + 1/z_i = 1/F) to the
  point at depth ``z_o`` on the chief ray; rays from a uniformly sampled circular aperture of diameter
  F / N converge there. Since z_i varies across a tilted sensor, the plane of sharp focus tilts (Scheimpflug).

Mitsuba's film puts pixel centres at +0.5; this is the one place where that is converted to OpenCV's
integer centres.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from scenes.optics.backend import dr, mi

PLUGIN_NAME = "scheimpflug"

#: Fixed-point iterations of the per-ray undistortion. The error shrinks per step by about the slope of the
#: distortion, ~abs(2 k1 r^2 + 4 k2 r^4 + 6 k3 r^6) + 2 abs(s) r (~1e-2 at Table 1's corners, r ~ 0.15), so for a
#: Brown-only lens like Table 1's, 8 iterations are far below float32 resolution.
UNDISTORT_ITERATIONS = 8
#: Iterations for a lens with any of the k3 / thin-prism terms. Those matter most on wide fields, where the
#: contraction is slowest. Measured (tests/test_lens_terms.py: plugin rays vs the float64 truth, 1600 x 1200
#: px, fx = 2000 px, tilt (2, -3) deg, abs(s_i) <= 1e-3, image corners at r = 0.48-0.58), worst error in
#: normalised units, where float32 rounding alone gives ~1e-7 (2e-4 px): k3 = 1 alone, k3 = 1 with Table 1's
#: k1, k2, with k1 = -0.3, or with k1 = +0.3 (9 % pincushion): at that floor with 8 iterations already; but
#: k1 = -0.3, k2 = 0.2, k3 = -1 (8 % barrel, k1 and k3 adding up): 2.4e-5 after 8, 6.2e-7 after 12, 1.0e-7
#: (the floor) after 16. Extra iterations are a few flops per ray. Brown-only lenses keep 8 so that their
#: renders stay bit-identical (with 12, one pixel of the paper rig's right camera in 315 596 moves by one
#: float32 ulp).
UNDISTORT_ITERATIONS_EXTRA_TERMS = 16

#: Lens terms beyond Brown k1, k2, p1, p2 (OpenCV's names); 0 = absent. The instrument does not model them.
EXTRA_LENS_TERMS = ("k3", "s1", "s2", "s3", "s4")


@dataclass(frozen=True)
class SensorSpec:
    """Everything the renderer needs to know about one camera.

    Intrinsics use the names of Table 1 of the paper (pixels, degrees); ``lens`` is ``"pinhole"`` or
    ``"thin"``. A thin lens needs ``focal_length_mm`` (the lens' F), ``f_number`` and ``pixel_pitch_mm``
    (so the image distance is ``fx * pixel_pitch_mm``).

    Distortion acts on the ideal image plane (normalised coordinates ``x, y``, ``r^2 = x^2 + y^2``) before
    the sensor tilt, with exactly OpenCV's definitions (``cv::projectPoints``, distCoeffs
    ``(k1, k2, p1, p2, k3, 0, 0, 0, s1, s2, s3, s4)``; rational k4..k6 are not implemented)::

        x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4
        y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4

    k1, k2, p1, p2 are the paper's Brown terms (eq 7), which :mod:`measurement.camera` also models. The
    remaining terms (all 0 by default, i.e. absent; a spec without them renders bit-identically as before
    they existed) are *true-lens* terms the instrument does not model, a lens-model-mismatch error source
    (DESIGN.md §7):

    * ``k3`` (unitless, r^6 radial term): it moves an image point by ``fx |k3| r^7`` px at radius r. On
      industrial C-mount lenses of 25-35 mm it is worth a few px at the image corners: the VIC-3D
      calibration of the Stereo-DIC Challenge 1.0 Sample 3 has kappa3 terms worth 1.6-3.3 px there. As a
      coefficient of r^6 its value depends on the field of view: abs(k3) up to ~1 with corners at r ~ 0.5
      (wide angle), while 2.5 px needs k3 ~ 7 at r = 0.25 (fx = 6000 px) and ~ 45 at the far corner of
      Table 1's left camera (r = 0.175, fx = 10 912 px, where k3 = 1 is only 0.06 px).
    * ``s1, s2`` (x) and ``s3, s4`` (y) (unitless): thin-prism distortion from decentred or tilted lens
      elements and a lens not parallel to the sensor (Weng, Cohen, Herniou 1992, "Camera calibration with
      distortion models and accuracy evaluation", IEEE PAMI 14(10):965-980); typical magnitudes
      abs(s_i) ~ 1e-4-1e-3. ``s1`` shifts a corner by ``fx s1 r^2`` px: 0.02-0.24 px on Table 1's rig,
      0.05-0.5 px at r = 0.5 with fx = 2000 px.

    All numeric fields must be finite (ValueError naming the field).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    alpha_deg: float = 0.0
    beta_deg: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    lens: str = "pinhole"
    focal_length_mm: float = 0.0
    f_number: float = 0.0
    pixel_pitch_mm: float = 0.00345
    # Appended after the existing fields so that positional construction keeps its meaning.
    k3: float = 0.0
    s1: float = 0.0
    s2: float = 0.0
    s3: float = 0.0
    s4: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name != "lens" and not np.isfinite(v):
                raise ValueError(f"sensor parameter {f.name} must be finite, got {v!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy} px")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height} px")
        if abs(self.alpha_deg) >= 45 or abs(self.beta_deg) >= 45:
            raise ValueError(f"sensor tilt must be below 45 deg, got alpha={self.alpha_deg}, beta={self.beta_deg}")
        if self.lens not in ("pinhole", "thin"):
            raise ValueError(f"lens must be 'pinhole' or 'thin', got {self.lens!r}")
        if self.lens == "thin":
            if self.focal_length_mm <= 0 or self.f_number <= 0 or self.pixel_pitch_mm <= 0:
                raise ValueError("a thin lens needs focal_length_mm > 0, f_number > 0 and pixel_pitch_mm > 0")
            if self.image_distance_mm <= self.focal_length_mm:
                raise ValueError(
                    f"image distance fx*pitch = {self.image_distance_mm:.3f} mm must exceed the focal length "
                    f"{self.focal_length_mm} mm for a real image")

    @property
    def image_distance_mm(self) -> float:
        return self.fx * self.pixel_pitch_mm

    @property
    def focus_distance_mm(self) -> float:
        """Object distance in sharp focus on the optical axis (thin-lens equation)."""
        v = self.image_distance_mm
        return 1.0 / (1.0 / self.focal_length_mm - 1.0 / v)

    def supersampled(self, factor: int) -> "SensorSpec":
        """The same sensor cut into ``factor x factor`` finer pixels (same optics, same field of view): fine pixel
        ``j`` is centred at coarse pixel coordinate ``(j + 0.5) / factor - 0.5``, so coarse pixel ``i`` is the mean
        of fine pixels ``factor i .. factor i + factor - 1`` along each axis."""
        s = int(factor)
        if s != factor or s < 1:
            raise ValueError(f"supersampling factor must be an integer >= 1, got {factor!r}")
        return replace(self, fx=self.fx * s, fy=self.fy * s, cx=s * self.cx + (s - 1) / 2.0,
                       cy=s * self.cy + (s - 1) / 2.0, width=self.width * s, height=self.height * s,
                       pixel_pitch_mm=self.pixel_pitch_mm / s)

    def with_(self, **changes) -> "SensorSpec":
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)


def distortion_terms(x, y, lens):
    """OpenCV's distortion split as ``x_d = x * radial + dx``, ``y_d = y * radial + dy``: the one formula of the
    truth side, for numpy arrays (:mod:`scenes.optics.projection`) and Dr.Jit arrays (the sensor plugin) alike.

    ``radial = 1 + k1 r^2 + k2 r^4 + k3 r^6``, ``dx = 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4``,
    ``dy = p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4``; ``lens`` has the attributes ``k1, k2, k3, p1, p2,
    s1..s4`` (a :class:`SensorSpec` or the plugin). The k3 and thin-prism terms are evaluated only when non-zero, so
    a lens without them gives bit for bit the Brown-only values (and the plugin traces the kernel it traced before
    they existed; where r^2 overflows, ``0 * inf`` would be NaN).
    """
    r2 = x * x + y * y
    if lens.k3 != 0.0:
        radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + lens.k3 * r2))
    else:
        radial = 1.0 + r2 * (lens.k1 + lens.k2 * r2)
    dx = 2.0 * lens.p1 * x * y + lens.p2 * (r2 + 2.0 * x * x)
    dy = lens.p1 * (r2 + 2.0 * y * y) + 2.0 * lens.p2 * x * y
    if lens.s1 != 0.0 or lens.s2 != 0.0:
        dx = dx + r2 * (lens.s1 + lens.s2 * r2)
    if lens.s3 != 0.0 or lens.s4 != 0.0:
        dy = dy + r2 * (lens.s3 + lens.s4 * r2)
    return radial, dx, dy


def sensor_axes(alpha_deg: float, beta_deg: float) -> np.ndarray:
    """Tilted sensor axes as columns (e1, e2, normal) in the camera frame, from Mitsuba's rotations."""
    rot = mi.ScalarTransform4f().rotate([0, 1, 0], beta_deg) @ mi.ScalarTransform4f().rotate([1, 0, 0], alpha_deg)
    m = np.array(rot.matrix, dtype=float)[:3, :3]
    return m


class ScheimpflugSensor(mi.Sensor):
    """Mitsuba sensor: tilted sensor behind a pinhole or thin lens, with Brown distortion (see module doc)."""

    def __init__(self, props):
        super().__init__(props)
        get = lambda name, default=0.0: float(props.get(name, default))  # noqa: E731
        self.fx, self.fy = get("fx"), get("fy")
        self.cx, self.cy = get("cx"), get("cy")
        self.k1, self.k2, self.p1, self.p2 = get("k1"), get("k2"), get("p1"), get("p2")
        self.k3 = get("k3")
        self.s1, self.s2, self.s3, self.s4 = get("s1"), get("s2"), get("s3"), get("s4")
        extra = any(getattr(self, name) != 0.0 for name in EXTRA_LENS_TERMS)
        self.undistort_iterations = UNDISTORT_ITERATIONS_EXTRA_TERMS if extra else UNDISTORT_ITERATIONS
        axes = sensor_axes(get("alpha_deg"), get("beta_deg"))
        self.e1 = [float(x) for x in axes[:, 0]]
        self.e2 = [float(x) for x in axes[:, 1]]
        self.thin_lens = props.get("lens", "pinhole") == "thin"
        # Read the lens properties in both modes: Mitsuba rejects unreferenced properties.
        self.focal_length_mm = get("focal_length_mm")
        f_number = get("f_number")
        self.image_distance_mm = self.fx * get("pixel_pitch_mm")
        if self.thin_lens:
            self.aperture_radius_mm = 0.5 * self.focal_length_mm / f_number
        self.m_needs_sample_3 = self.thin_lens

    def _chief_ray(self, position_sample):
        film = self.film()
        size = film.crop_size()
        offset = film.crop_offset()
        # Film samples are relative to the crop window; pixel centres move from +0.5 (Mitsuba) to 0 (OpenCV).
        u = offset[0] + position_sample.x * size[0] - 0.5
        v = offset[1] + position_sample.y * size[1] - 0.5
        s = (u - self.cx) / self.fx
        t = (v - self.cy) / self.fy
        e1, e2 = self.e1, self.e2
        px = s * e1[0] + t * e2[0]
        py = s * e1[1] + t * e2[1]
        pz = 1.0 + s * e1[2] + t * e2[2]
        xd, yd = px / pz, py / pz
        xn, yn = mi.Float(xd), mi.Float(yd)
        for _ in range(self.undistort_iterations):
            radial, dx, dy = distortion_terms(xn, yn, self)
            xn = (xd - dx) / radial
            yn = (yd - dy) / radial
        return xn, yn, pz

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        xn, yn, pz = self._chief_ray(sample2)
        if self.thin_lens:
            z_image = self.image_distance_mm * pz          # distance of this sensor point behind the lens
            z_object = 1.0 / (1.0 / self.focal_length_mm - 1.0 / z_image)
            focus = mi.Point3f(xn * z_object, yn * z_object, z_object)
            disk = mi.warp.square_to_uniform_disk_concentric(sample3) * self.aperture_radius_mm
            origin = mi.Point3f(disk.x, disk.y, 0.0)
            direction = dr.normalize(mi.Vector3f(focus - origin))
        else:
            origin = mi.Point3f(0.0, 0.0, 0.0)
            direction = dr.normalize(mi.Vector3f(xn, yn, 1.0))
        to_world = self.world_transform()
        ray = mi.Ray3f(to_world @ origin, to_world @ mi.Vector3f(direction))
        ray.time = time
        return ray, mi.Float(1.0)

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, weight = self.sample_ray(time, sample1, sample2, sample3, active)
        ray_diff = mi.RayDifferential3f(ray)
        ray_diff.has_differentials = False
        return ray_diff, weight

    def to_string(self):
        return f"ScheimpflugSensor[fx={self.fx}, fy={self.fy}, thin_lens={self.thin_lens}]"


mi.register_sensor(PLUGIN_NAME, lambda props: ScheimpflugSensor(props))


def to_world_matrix(R_cam_from_world: np.ndarray, t_cam_from_world_mm: np.ndarray) -> np.ndarray:
    """4x4 ``T_world_from_cam`` for a pose ``X_cam = R X_world + t`` (mm)."""
    R = np.asarray(R_cam_from_world, dtype=float)
    t = np.asarray(t_cam_from_world_mm, dtype=float).reshape(3)
    M = np.eye(4)
    M[:3, :3] = R.T
    M[:3, 3] = -R.T @ t
    return M


def sensor_dict(spec: SensorSpec, R_cam_from_world, t_cam_from_world_mm, spp: int, seed: int = 0,
                crop: tuple[int, int, int, int] | None = None, sampler: str = "stratified") -> dict:
    """Mitsuba scene-dict entry for ``spec`` at the given pose.

    Every numeric field of ``spec`` except width/height becomes a float property of the plugin (the lens
    terms k3, s1..s4 included, 0.0 when absent); ``lens`` stays a string.
    ``crop = (x0, y0, width, height)`` in pixels renders only that window of the full sensor.
    """
    film = {"type": "hdrfilm", "width": int(spec.width), "height": int(spec.height),
            "rfilter": {"type": "box"}, "pixel_format": "luminance", "component_format": "float32"}
    if crop is not None:
        x0, y0, w, h = (int(c) for c in crop)
        if x0 < 0 or y0 < 0 or w <= 0 or h <= 0 or x0 + w > spec.width or y0 + h > spec.height:
            raise ValueError(f"crop {crop} is outside the {spec.width} x {spec.height} sensor")
        film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=w, crop_height=h)
    if sampler == "stratified" and round(spp ** 0.5) ** 2 != spp:
        sampler = "independent"   # Mitsuba's stratified sampler would silently round spp up to a square
    d = {"type": PLUGIN_NAME, "to_world": mi.ScalarTransform4f(to_world_matrix(R_cam_from_world, t_cam_from_world_mm)),
         "film": film, "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)}}
    for key, value in spec.to_dict().items():
        if key in ("width", "height"):
            continue
        d[key] = value if isinstance(value, str) else float(value)
    return d
