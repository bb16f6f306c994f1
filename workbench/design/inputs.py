"""What ``workbench design`` reads: the specimen, the hardware on offer, the constraints (strict TOML).

A design file has the tables ``[specimen]``, ``[[camera]]`` (one or more), ``[[lens]]`` (one or more),
``[adapter]``, ``[lighting]``, ``[constraints]``, ``[search]`` and ``[verify]``; every key is listed with its unit
and default by ``workbench parameters`` (prefix ``design.``). Loading is strict like every config of the project
(:mod:`workbench.config`): an unknown key, a wrong type or a value out of its bounds is refused naming the file
and the key; cross-checks that need two keys (a range whose low end is above its high end, a specimen larger than
any field of view on offer) are refused naming both, before any work (:func:`check_design`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from workbench.config import ConfigError, from_dict, read_mapping

#: Catalog specimens a design may name (``workbench catalog``); ``beam`` is the paper's three-point bending beam.
CATALOG_NAMES = ("plate_with_hole", "notched_coupon", "pressurised_cylinder", "beam")
#: The Scheimpflug tilt the instrument's camera model holds (:data:`measurement.camera.MAX_TILT_DEG`), deg.
MAX_ADAPTER_TILT_DEG = 45.0


def _f(default, doc: str = "", **meta):
    return field(default=default, metadata={"doc": doc, **meta})


@dataclass(frozen=True)
class SpecimenInput:
    """The specimen and what is to be measured on it: a catalog name, a user's mesh/FE file, or a plane."""

    catalog: str = _f("", "a catalog specimen (its front face, as `workbench catalog` writes it)",
                      choices=("",) + CATALOG_NAMES)
    mesh: str = _f("", "a user's mesh or FE file (any format of scenario.specimen.mesh); its front face (-z) is "
                       "measured; a relative path is relative to the design file")
    unit: str = _f("mm", "the mesh file's length unit", choices=("mm", "m", "cm", "um", "in"))
    plane_mm: tuple[float, float] | None = _f(None, "or a plane of this width x height, mm (facing the rig)",
                                              min=1e-3, max=1e5)
    roi_mm: tuple[float, float, float, float] | None = _f(
        None, "the region of interest on the front face, (x0, y0, x1, y1) mm in the specimen frame; absent: the whole "
              "face seen from the front", min=-1e5, max=1e5)
    depth_range_mm: float = _f(0.0, "the out-of-plane travel of the face during the test (+/- half of it about the "
                                    "reference), mm: every point must stay measurable over it", min=0.0, max=1e4)
    quantity: str = _f("displacement", "what matters: 'displacement' or 'strain'", choices=("displacement", "strain"))
    component: str = _f("out-of-plane", "which: 'in-plane' (U, V or exx, eyy) or 'out-of-plane' (W)",
                        choices=("in-plane", "out-of-plane"))
    speckle_mm: float | None = _f(None, "the painted speckle's diameter, mm; absent: each candidate rig's own "
                                        "(speckle.size_px at the face centre), as one paints for a rig",
                                  min=1e-4, max=100.0)
    speckle_px: float = _f(4.0, "speckle diameter in pixels at the face centre when speckle_mm is absent", min=2.0,
                           max=50.0)
    speckle_contrast: float = _f(0.8, "paint contrast: grey difference of bright and dark phase over full scale "
                                      "(scenes.surfaces.paint)", min=0.05, max=1.0)
    sample_points: tuple[int, int] = _f((13, 9), "ROI sample grid for the prediction (across, down)", min=2, max=200)


@dataclass(frozen=True)
class CameraInput:
    """One camera on offer (EMVA 1288 data-sheet figures)."""

    name: str = _f("2456 x 2058 CCD", "a label for tables and files")
    width_px: int = _f(2456, "image width, px", min=64, max=100000)
    height_px: int = _f(2058, "image height, px", min=64, max=100000)
    pixel_pitch_um: float = _f(3.45, "pixel pitch, um (the paper gives none; 3.45 um is typical of its CCD)",
                               min=0.5, max=100.0)
    read_noise_e: float = _f(10.0, "temporal dark noise, electrons", min=0.0, max=1e4)
    full_well_e: float = _f(10000.0, "saturation capacity, electrons", min=10.0, max=1e7)
    bit_depth: int = _f(8, "bits per pixel of the images the instrument reads", choices=(8, 10, 12, 16))

    @property
    def pixel_pitch_mm(self) -> float:
        return self.pixel_pitch_um * 1e-3

    @property
    def full_scale_grey(self) -> float:
        return float(2 ** self.bit_depth - 1)

    @property
    def electrons_per_grey(self) -> float:
        return self.full_well_e / self.full_scale_grey

    @property
    def read_noise_grey(self) -> float:
        return self.read_noise_e / self.electrons_per_grey


@dataclass(frozen=True)
class LensInput:
    """One lens on offer (a thin lens of focal length F, its f-number range)."""

    name: str = _f("50 mm", "a label for tables and files")
    focal_length_mm: float = _f(50.0, "focal length F, mm", min=1.0, max=5000.0)
    f_number_min: float = _f(2.8, "widest aperture (smallest f-number)", min=0.5, max=128.0)
    f_number_max: float = _f(16.0, "smallest aperture (largest f-number)", min=0.5, max=128.0)


@dataclass(frozen=True)
class AdapterInput:
    """The Scheimpflug adapter between lens and camera: how far it tilts the lens against the sensor."""

    tilt_max_deg: float = _f(10.0, "largest tilt the adapter holds about each axis, deg (0: no adapter: "
                                   "only untilted rigs)", min=0.0, max=89.0)


@dataclass(frozen=True)
class LightingInput:
    """The exposure budget: how bright the specimen images at a reference aperture in the time the test allows."""

    mean_fraction: float = _f(0.5, "mean grey of the specimen over full scale at f_number and unit magnification "
                                   "factor (1 + m = 1); image irradiance goes as 1 / (N (1 + m))^2", min=1e-3,
                              max=1.0)
    f_number: float = _f(8.0, "the f-number that mean_fraction is stated at", min=0.5, max=128.0)
    max_fraction: float = _f(0.9, "brightest paint as a fraction of full scale the exposure may reach (more light "
                                  "is cut by a shorter exposure: no saturation)", min=0.1, max=1.0)


@dataclass(frozen=True)
class ConstraintsInput:
    """Where the cameras may go."""

    working_distance_mm: tuple[float, float] = _f((300.0, 600.0), "camera centre to the specimen's centre, range, mm",
                                                  min=1.0, max=1e6)
    stereo_angle_deg: tuple[float, float] = _f((15.0, 35.0), "angle between the two lines of sight, range, deg",
                                               min=1.0, max=150.0)
    min_standoff_mm: float = _f(0.0, "closest any camera centre may come to the specimen's face plane, mm", min=0.0,
                                max=1e6)
    max_side_mm: float | None = _f(None, "space on either side: largest sideways offset of a camera from the "
                                         "specimen's centre, mm (absent: no limit)", min=0.0, max=1e6)


@dataclass(frozen=True)
class SearchInput:
    """The candidate grid and the instrument's settings the prediction is made for."""

    distances: int = _f(6, "working distances tried over the allowed range", min=1, max=100)
    angles: int = _f(5, "stereo angles tried over the allowed range", min=1, max=100)
    f_numbers: tuple[float, ...] = _f((2.8, 4.0, 5.6, 8.0, 11.0, 16.0), "f-numbers tried (each lens: those in its "
                                                                          "range)", min=0.5, max=128.0)
    subset_px: int = _f(33, "DIC subset size, px (odd)", min=5, max=401)
    step_px: int = _f(8, "DIC grid step, px", min=1, max=200)
    order: int = _f(1, "shape function order", choices=(1, 2))
    strain_window: int = _f(9, "strain window, grid points (a virtual strain gauge of step x (window - 1) + subset "
                                "px)", min=3, max=101)
    wavelength_nm: float = _f(550.0, "light wavelength for diffraction, nm", min=300.0, max=1100.0)
    in_focus_blur_px: float = _f(1.0, "a point is in focus where its defocus blur circle is at most this, px",
                                 min=0.01, max=100.0)
    min_in_focus_fraction: float = _f(0.0, "a candidate needs at least this fraction of the ROI in focus over the "
                                           "depth range", min=0.0, max=1.0)


@dataclass(frozen=True)
class VerifyInput:
    """Rendering the chosen and the best untilted rig, and measuring them with the instrument."""

    enabled: bool = _f(True, "render and measure the two rigs (false: prediction only)")
    scale: float = _f(1.0, "image resolution of the verification renders relative to the camera's", min=0.05,
                      max=1.0)
    repeats: int = _f(2, "static pairs per rig (fresh sensor noise each)", min=1, max=20)
    mc_target_grey: float = _f(1.5, "Monte-Carlo noise left in the defocused pixels of a render, grey: a static "
                                     "pair's two images share the render, so to them it is texture, not noise; "
                                     "the deformed state's error includes it", min=0.01, max=5.0)


@dataclass(frozen=True)
class DesignInput:
    """A whole design file (module notes)."""

    specimen: SpecimenInput = field(default_factory=SpecimenInput)
    camera: tuple[CameraInput, ...] = _f((CameraInput(),), "cameras on offer ([[camera]] tables)", min_items=1)
    lens: tuple[LensInput, ...] = _f((LensInput(),), "lenses on offer ([[lens]] tables)", min_items=1)
    adapter: AdapterInput = field(default_factory=AdapterInput)
    lighting: LightingInput = field(default_factory=LightingInput)
    constraints: ConstraintsInput = field(default_factory=ConstraintsInput)
    search: SearchInput = field(default_factory=SearchInput)
    verify: VerifyInput = field(default_factory=VerifyInput)
    seed: int = _f(0, "seed of the speckle and of every noise draw", min=0, max=2 ** 31 - 1)


def _range(values, key: str) -> None:
    lo, hi = values
    if lo > hi:
        raise ConfigError(f"{key}: the low end {lo:g} is above the high end {hi:g}")


def check_design(design: DesignInput, where: str = "design") -> DesignInput:
    """Cross-checks of keys that single bounds cannot make; raises :class:`ConfigError` naming the keys."""
    s = design.specimen
    given = [k for k, v in (("catalog", s.catalog), ("mesh", s.mesh), ("plane_mm", s.plane_mm)) if v]
    if len(given) != 1:
        raise ConfigError(f"{where}: specimen: give exactly one of specimen.catalog, specimen.mesh, specimen.plane_mm"
                          + (f" (got {', '.join('specimen.' + g for g in given)})" if given else ""))
    if s.roi_mm is not None and not (s.roi_mm[0] < s.roi_mm[2] and s.roi_mm[1] < s.roi_mm[3]):
        raise ConfigError(f"{where}: specimen.roi_mm: expected (x0, y0, x1, y1) with x0 < x1 and y0 < y1, got "
                          f"{list(s.roi_mm)}")
    if s.quantity == "strain" and s.component == "out-of-plane":
        raise ConfigError(f"{where}: specimen.quantity = 'strain' with specimen.component = 'out-of-plane': a surface "
                          "has no out-of-plane strain; choose component = 'in-plane'")
    if design.search.subset_px % 2 == 0:
        raise ConfigError(f"{where}: search.subset_px: must be odd, got {design.search.subset_px}")
    for i, lens in enumerate(design.lens):
        if lens.f_number_min > lens.f_number_max:
            raise ConfigError(f"{where}: lens[{i}].f_number_min ({lens.f_number_min:g}) is above lens[{i}]."
                              f"f_number_max ({lens.f_number_max:g})")
        if not any(lens.f_number_min - 1e-9 <= N <= lens.f_number_max + 1e-9 for N in design.search.f_numbers):
            raise ConfigError(f"{where}: lens[{i}] ({lens.name}): none of search.f_numbers "
                              f"{list(design.search.f_numbers)} is within its f-number range "
                              f"[{lens.f_number_min:g}, {lens.f_number_max:g}]")
    if design.adapter.tilt_max_deg >= MAX_ADAPTER_TILT_DEG:
        raise ConfigError(f"{where}: adapter.tilt_max_deg: {design.adapter.tilt_max_deg:g} deg is beyond what a "
                          f"Scheimpflug adapter holds and the camera model describes (< {MAX_ADAPTER_TILT_DEG:g} deg)")
    _range(design.constraints.working_distance_mm, f"{where}: constraints.working_distance_mm")
    _range(design.constraints.stereo_angle_deg, f"{where}: constraints.stereo_angle_deg")
    for i, cam in enumerate(design.camera):
        if cam.width_px < design.search.subset_px * 2 or cam.height_px < design.search.subset_px * 2:
            raise ConfigError(f"{where}: camera[{i}] ({cam.name}): {cam.width_px} x {cam.height_px} px holds fewer "
                              f"than two subsets of search.subset_px = {design.search.subset_px} px across")
    return design


def load_design(path) -> DesignInput:
    """Read and check a design file (TOML or JSON); errors name the file and the key. A relative
    ``specimen.mesh`` is made relative to the file."""
    from dataclasses import replace

    path = Path(path)
    data = read_mapping(path)
    try:
        design = from_dict(DesignInput, data, "design")
        check_design(design)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None
    if design.specimen.mesh and not Path(design.specimen.mesh).is_absolute():
        design = replace(design, specimen=replace(design.specimen,
                                                  mesh=str((path.parent / design.specimen.mesh).resolve())))
    if design.specimen.mesh and not Path(design.specimen.mesh).is_file():
        raise ConfigError(f"{path}: specimen.mesh: no such file {design.specimen.mesh}")
    return design


def f_numbers_of(lens: LensInput, search: SearchInput) -> list[float]:
    """The search's f-numbers within the lens's range."""
    return [float(N) for N in search.f_numbers if lens.f_number_min - 1e-9 <= N <= lens.f_number_max + 1e-9]
