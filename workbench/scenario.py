"""Scenarios and instruments as data (DESIGN §6): what is rendered, and how it is measured.

A :class:`Scenario` is the complete description of one virtual experiment on the truth side: the rig and its
lens, the calibration target and its imperfections, the speckle, the motion states, every error source, the
render settings and the seed. An :class:`Instrument` is the measurement side: calibration model, subset,
step, shape function, interpolant, pre-filter, strain window. Both are frozen dataclasses that load from and
save to TOML/JSON (:mod:`workbench.config`: unknown keys and wrong types are refused naming the key) and have
a stable content hash.

Every error source is off by default and is one physical parameter with its unit in the name; the
docstrings give realistic ranges and their sources. The instrument never sees these parameters: it sees only
the rendered images, as with a real rig.

A scenario renders into one or more *datasets* (:func:`dataset_parts`): each is keyed by the hash of only
the sections that change its images, so a study that varies, say, the stage error reuses the calibration
renders of every case.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from workbench.config import SCHEMA_VERSION, content_hash, hash_of, to_dict

EXPERIMENTS = ("dic2d", "rigid_motion", "specimen")


def _f(default, doc: str = "", **meta):
    """A config field with its documentation (unit, range, source) and bounds/choices."""
    return field(default=default, metadata={"doc": doc, **meta})


@dataclass(frozen=True)
class RigConfig:
    """The true stereo rig (:func:`workbench.rigs.get_rig`) and its lens."""

    name: str = _f("paper", "true rig: 'paper' (Table 1) or 'scheimpflug' (tilts solved for the face)",
                   choices=("paper", "scheimpflug"))
    scale: float = _f(0.25, "image resolution relative to the paper's 2456 x 2058 px (focal lengths scale too)",
                      min=0.05, max=1.0)
    lens: str = _f("pinhole", "'pinhole' or 'thin' (defocus: a thin lens focused on the face centre)",
                   choices=("pinhole", "thin"))
    f_number: float = _f(8.0, "the lens' f-number: a thin lens' defocus grows as 1/N, every lens' diffraction as N "
                              "(rig.diffraction); f/2.8-f/16 in DIC practice",
                         min=0.5, max=64.0)
    calibration: str = _f("", "specimen scenarios: a calibration file of one's own rig (this project's JSON, OpenCV, "
                              "DICe, VIC-3D, MATLAB) as the true rig instead of 'name', scaled by 'scale'; a relative "
                              "path is relative to the scenario file")
    focus_offset_mm: float = _f(0.0, "thin lens focused this far beyond the face centre along the line of sight "
                                     "(a focusing error; the depth of field at f/8 and 376 mm is a few mm)",
                                min=-200.0, max=1000.0)
    diffraction: bool = _f(True, "the lens diffracts (Airy pattern of radius 1.22 wavelength f_number, any lens model, "
                                 "pinhole included): a rendered image is what the camera records (false: ideal optics)")
    wavelength_nm: float = _f(550.0, "light wavelength for the diffraction, nm", min=300.0, max=1100.0)
    pixel_fill_factor: float = _f(1.0, "the pixels' light-collecting aperture, a square of this fraction of the pitch "
                                       "(1: the whole pixel, as microlenses make it; smaller apertures alias more)",
                                  min=0.1, max=1.0)


@dataclass(frozen=True)
class RenderConfig:
    """Rendering and the sensor: Monte-Carlo noise (spp), read and shot noise, bit depth."""

    spp: int = _f(64, "samples per pixel (stratified); Monte-Carlo noise ~ 1/sqrt(spp)", min=1, max=4096)
    bit_depth: int = _f(8, "bits per pixel of the written images; 0: float images, no quantisation (dic2d only)",
                        choices=(0, 8, 16))
    read_noise_grey: float = _f(1.0, "Gaussian read noise, grey levels of the bit depth (machine-vision "
                                     "cameras: 0.5-3 grey at 8 bit; EMVA 1288 data sheets)", min=0.0, max=100.0)
    electrons_per_grey: float | None = _f(None, "shot noise: sensor gain in electrons per grey level (absent: "
                                                "no shot noise); 5-50 e-/grey at 8 bit for 10 ke- full well",
                                          min=1e-3, max=1e6)
    board_renderer: str = _f("auto", "calibration-board views: 'auto' renders the exact box-filtered pixel of the "
                                     "printed polygons where a view allows it (pinhole, no occlusion; else Mitsuba "
                                     "at spp), 'mitsuba' always Monte Carlo at spp", choices=("auto", "mitsuba"))
    mc_target_grey: float | None = _f(None, "specimen scenarios: Monte-Carlo noise target (grey RMS) of the pixels "
                                            "the deterministic renderer leaves to Mitsuba (occluding edges, "
                                            "thin-lens blur); absent: 0.3", min=0.01, max=10.0)
    speckle_renderer: str = _f("auto", "speckle states: 'auto' renders without Monte Carlo where a view allows it "
                                       "(pinhole: exact coverage, Gauss-Legendre quadrature of the speckle; else "
                                       "Mitsuba at spp), 'mitsuba' always Monte Carlo at spp",
                               choices=("auto", "mitsuba"))
    noise_seed: int | None = _f(None, "seed of the sensor noise alone (absent: the scenario's seed): the same scene "
                                      "with a new noise draw, e.g. to test an uncertainty", min=0, max=2 ** 31 - 1)
    supersample: int = _f(1, "speckle states: pixels rendered supersample x supersample finer, then the lens' "
                             "diffraction and each block's mean, so the optics low-pass a sharp paint before the "
                             "pixels sample it as in a camera (1: the box-filtered pixels, enough for soft speckle "
                             "edges)", min=1, max=8)


@dataclass(frozen=True)
class SpeckleConfig:
    """The speckle pattern, in image pixels (it scales with the rig)."""

    size_px: float | None = _f(None, "speckle size in px: autocorrelation size in 2-D (absent: 4 px), painted "
                                     "speckle size at the working distance in 3-D (absent: 5 px); 3-5 px "
                                     "recommended (iDICs Good Practices Guide 2018)", min=1.5, max=30.0)
    density: float = _f(0.5, "fraction of the surface covered by speckles (0.4-0.6 typical)", min=0.05, max=0.95)
    contrast: float = _f(1.0, "pattern contrast relative to the default (grey std 30 of mean 128 in 2-D, "
                              "0.8 of the radiance range in 3-D)", min=0.05, max=1.2)
    edge_px: float | None = _f(None, "specimen scenarios: the painted speckles' edge width (Gaussian sigma) in px at "
                                     "the working distance (absent: speckle / 6, soft edges as sprayed paint has); a "
                                     "sharp paint (0.1 px) aliases unless the lens' diffraction low-pass it",
                               min=0.02, max=10.0)


@dataclass(frozen=True)
class Image2DConfig:
    """The 2-D DIC experiment: an exactly translated periodic speckle image pair (``dic2d``)."""

    size_px: int = _f(256, "image side (square images)", min=32, max=4096)
    shift_x_px: float = _f(0.25, "imposed translation along x (px)", min=-8.0, max=8.0)
    shift_y_px: float = _f(0.0, "imposed translation along y (px)", min=-8.0, max=8.0)


@dataclass(frozen=True)
class TargetConfig:
    """The calibration board (the paper's 12 x 9 squares of 5 mm) and its imperfections."""

    calibration_views: int = _f(30, "stereo views used for calibration (the paper: 30)", min=3, max=500)
    square_mm: float = _f(5.0, "nominal square size the instrument is told (the paper: 5 mm)", min=0.5, max=100.0)
    max_tilt_deg: float = _f(40.0, "largest board tilt of the random views (small: 'too flat' views)",
                             min=0.0, max=60.0)
    print_scale_error: float = _f(0.0, "printed squares are (1 + e) x nominal; office printers and paper "
                                       "shrinkage: 1e-3-5e-3", min=-0.1, max=0.1)
    bow_sag_mm: float = _f(0.0, "board bow: sag at the centre of the checkered area (positive: towards the "
                                "cameras); cardboard 0.1-2 mm over 100 mm", min=-10.0, max=10.0)
    bow_axis: str = _f("y", "bow: cylinder about the board's 'x' or 'y' axis, or a 'sphere'",
                       choices=("x", "y", "sphere"))
    corner_noise_mm: float = _f(0.0, "printed corner position noise (std, in-plane); printers 0.005-0.03 mm",
                                min=0.0, max=1.0)


@dataclass(frozen=True)
class MotionConfig:
    """The stage states of the rigid-motion test and the stage's own errors."""

    max_mm: float = _f(10.0, "largest stage travel (the paper: 10 mm)", min=0.001, max=100.0)
    step_mm: float = _f(1.0, "stage step (the paper: 1 mm)", min=0.001, max=100.0)
    return_to_zero: bool = _f(False, "also measure the way back (0 -> max -> 0), as the paper's protocol")
    stage_scale_error: float = _f(0.0, "the stage really moves (1 + e) x its reading; precision stages "
                                       "1e-4-1e-3 (PI, Newport data sheets)", min=-0.1, max=0.1)
    stage_straightness_um: float = _f(0.0, "peak lateral deviation over the travel (µm); 1-10 µm over "
                                           "25-100 mm (data sheets)", min=0.0, max=1000.0)
    stage_axis_tilt_deg: float = _f(0.0, "true stage axis tilted from the nominal (deg)", min=-10.0, max=10.0)
    stage_rotation_urad_per_mm: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), "carriage pitch/yaw/roll: rotation vector per mm of travel, world (= left camera) frame, "
                         "µrad/mm, about the face centre; ball-bearing stages 1-5 µrad/mm (data sheets)",
        min=-1e4, max=1e4)


@dataclass(frozen=True)
class DriftConfig:
    """Camera drift between states (thermal or mechanical): a small extrinsic change, linear in the state."""

    camera: str = _f("right", "which camera drifts", choices=("left", "right"))
    translation_um_per_state: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), "camera translation per state, its own frame (µm); warm-up drift of 0.1-0.5 px over "
                         "an hour (Ma, Pang, Ma 2012, Meas. Sci. Technol. 23 025403)", min=-1e4, max=1e4)
    rotation_urad_per_state: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), "camera rotation vector per state, its own frame (µrad)", min=-1e5, max=1e5)


@dataclass(frozen=True)
class IlluminationConfig:
    """Illumination change between states (applied to the scene radiance before sensor noise)."""

    gain_per_state: float = _f(0.0, "relative brightness change per state (a few % over a test)",
                               min=-0.2, max=0.2)
    offset_grey_per_state: float = _f(0.0, "grey levels added per state", min=-50.0, max=50.0)
    gradient_per_state: float = _f(0.0, "relative brightness ramp across the image width per state",
                                   min=-0.2, max=0.2)


@dataclass(frozen=True)
class LensConfig:
    """Terms of the TRUE lens that the instrument's model (k1 k2 p1 p2) does not have."""

    k3: float = _f(0.0, "radial r^6 term (OpenCV k3); worth 1.6-3.3 px at the corners of the DIC Challenge "
                        "1.0 Sample 3 calibration; on the paper rig k3 = 50 moves the far corner ~2.8 px",
                   min=-500.0, max=500.0)
    s1: float = _f(0.0, "thin prism x r^2 (OpenCV s1); 1e-4-1e-3 (Weng et al. 1992)", min=-0.1, max=0.1)
    s2: float = _f(0.0, "thin prism x r^4 (OpenCV s2)", min=-0.1, max=0.1)
    s3: float = _f(0.0, "thin prism y r^2 (OpenCV s3)", min=-0.1, max=0.1)
    s4: float = _f(0.0, "thin prism y r^4 (OpenCV s4)", min=-0.1, max=0.1)


@dataclass(frozen=True)
class SpecimenConfig:
    """A specimen of one's own (experiment ``specimen``): a surface mesh or an FE result, placed before the rig
    and painted (:mod:`scenes.specimens.mesh_specimen`). State 0 is the first chosen step (the reference)."""

    mesh: str = _f("", "the mesh or FE result file: STL, PLY, OBJ, GLB (surfaces), VTU, VTK, Gmsh .msh, Abaqus .inp, "
                       "Exodus .e/.exo (every time step), ParaView .pvd; a relative path is relative to the scenario "
                       "file")
    field: str = _f("", "nodal displacement field: a vector field's name, or 'x_name,y_name,z_name'; empty: the one "
                        "field named like a displacement")
    unit: str = _f("mm", "the file's length unit (checked against the mesh's size)", choices=("mm", "m", "cm", "um", "in"))
    steps: tuple[int, ...] | None = _f(None, "time-step indices to render (negative from the end); absent: all")
    times: tuple[float, ...] | None = _f(None, "or the time steps at these times")
    origin_mm: tuple[float, float, float] | None = _f(
        None, "the mesh point put where the rig's optical axes meet (file frame, file unit); absent: the centre of "
              "the mesh's bounding box in x and y, its smallest z (the mesh's -z faces the cameras)")
    rotation_deg: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "rotation of the mesh about its x, then y, then "
                                                                   "z axis before it is placed (deg)",
                                                  min=-360.0, max=360.0)
    offset_mm: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "shift after placing, specimen frame (x along the "
                                                                 "image rows, y down, z away from the cameras), mm",
                                               min=-1e4, max=1e4)
    paint: str = _f("speckle", "'speckle' or 'checker' (geometry checks)", choices=("speckle", "checker"))
    paint_method: str = _f("sprayed", "'sprayed' (projected along paint_direction; stretched on slopes) or "
                                      "'wrapped' (a printed sheet: on a cylinder around axis_*, by arc length)",
                           choices=("sprayed", "wrapped"))
    speckle_mm: float | None = _f(None, "speckle diameter on the surface, mm; absent: speckle.size_px pixels at the "
                                        "working distance", min=1e-3, max=100.0)
    texel_mm: float | None = _f(None, "paint texture resolution, mm (absent: speckle / 5)", min=1e-4, max=10.0)
    checker_mm: float = _f(2.0, "checker square side, mm", min=0.01, max=100.0)
    paint_direction: tuple[float, float, float] = _f((0.0, 0.0, 1.0), "paint travel direction, specimen frame "
                                                                       "(default: from the cameras' side)",
                                                     min=-1.0, max=1.0)
    axis_point_mm: tuple[float, float, float] | None = _f(None, "cylinder axis point for wrapped paint, specimen "
                                                               "frame (after placing), mm", min=-1e4, max=1e4)
    axis_direction: tuple[float, float, float] | None = _f(None, "cylinder axis direction, specimen frame",
                                                           min=-1.0, max=1.0)
    max_paint_angle_deg: float = _f(80.0, "faces turned further than this from the paint stay unpainted",
                                    min=1.0, max=89.0)
    base_grey: float = _f(0.5, "radiance of unpainted faces", min=0.0, max=1.0)
    rigid_states: int = _f(0, "extra states moving the last one rigidly (a stage), each by rigid_step_*", min=0,
                           max=100)
    rigid_step_mm: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "translation per rigid state, specimen frame",
                                                   min=-100.0, max=100.0)
    rigid_step_deg: tuple[float, float, float] = _f((0.0, 0.0, 0.0), "rotation per rigid state about the specimen "
                                                                      "origin (x, y, z axes)", min=-30.0, max=30.0)
    static_pair: bool = _f(True, "end with a static state: state 0 again with new sensor noise, moved rigidly in its "
                                 "plane by static_offset_px (the noise floor the instrument reaches on this scene)")
    static_offset_px: tuple[float, float] = _f((0.5, 0.5), "the static state's rigid move along the specimen's x and "
                                               "y, in pixel footprints at the working distance: it samples other paint "
                                               "points than the reference, so its floor holds every error a moved "
                                               "specimen carries but the motion's ((0, 0): the same points again)",
                                               min=-10.0, max=10.0)
    grazing_limit_deg: float = _f(70.0, "points seen more obliquely than this are masked", min=10.0, max=89.0)
    sagitta_px: float = _f(0.02, "largest distance between the flat pieces rendered and the curved FE faces, in "
                                 "pixel footprints at the working distance (the truth is the curved surface's)",
                           min=1e-4, max=1.0)
    truth_step_px: int = _f(2, "per-state truth arrays on every n-th pixel (material points and masks: every pixel)",
                            min=1, max=64)


@dataclass(frozen=True)
class Scenario:
    """One virtual experiment, truth side. ``experiment`` says which parts are used:

    * ``dic2d``: ``image2d``, ``speckle``, ``render`` (noise, bit depth), ``seed``;
    * ``rigid_motion``: ``rig``, ``target`` (calibration views), ``speckle``, ``motion``, ``drift``,
      ``illumination``, ``lens``, ``render``, ``seed``;
    * ``specimen``: ``rig``, ``specimen`` (a mesh or FE file of one's own), ``speckle``, ``render``, ``seed``.
    """

    experiment: str = _f("dic2d", "which virtual experiment", choices=EXPERIMENTS)
    seed: int = _f(0, "seeds every random thing (speckle, poses, sampler, noise)", min=0, max=2 ** 31 - 1)
    rig: RigConfig = field(default_factory=RigConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    speckle: SpeckleConfig = field(default_factory=SpeckleConfig)
    image2d: Image2DConfig = field(default_factory=Image2DConfig)
    target: TargetConfig = field(default_factory=TargetConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    drift: DriftConfig = field(default_factory=DriftConfig)
    illumination: IlluminationConfig = field(default_factory=IlluminationConfig)
    lens: LensConfig = field(default_factory=LensConfig)
    specimen: SpecimenConfig = field(default_factory=SpecimenConfig)


@dataclass(frozen=True)
class Instrument:
    """The measurement settings (the instrument side of a study)."""

    calibration: str = _f("rendered", "'rendered' (calibrate from the rendered board views) or 'true' (the true "
                                      "rig, no calibration error)", choices=("rendered", "true"))
    calibration_model: str = _f("rmm", "tilt model: the paper's 'rmm' or the conventional 'pinhole'",
                                choices=("rmm", "pinhole"))
    subset_px: int = _f(33, "subset size (odd)", min=5, max=401)
    step_px: int = _f(10, "grid step between points of interest", min=1, max=400)
    shape_order: int = _f(2, "subset shape function order", choices=(1, 2))
    interpolation: str = _f("biquintic", "sub-pixel interpolant", choices=("biquintic", "bicubic"))
    prefilter_sigma_px: float = _f(0.0, "Gaussian pre-filter of both images (0: none)", min=0.0, max=5.0)
    strain_window: int = _f(15, "strain window in points (k x k)", min=3, max=101)

    def __post_init__(self):
        if self.subset_px % 2 == 0:
            raise ValueError(f"subset_px must be odd, got {self.subset_px}")


#: Board renderer choice -> the tag that enters the calibration dataset's hash (a new version of a renderer
#: that changes its images gets a new tag).
BOARD_RENDERER_TAGS = {"auto": "exact-polygon/1 else mitsuba", "mitsuba": "mitsuba"}
#: The same for the speckle states (the quadrature order is part of the renderer's version).
SPECKLE_RENDERER_TAGS = {
    "auto": "polygon-quadrature/2 order 6, thin lens in focus <= 0.1 px + flat blurred faces defocus-quadrature/2 "
            "+ mitsuba-adaptive, else mitsuba",
    "mitsuba": "mitsuba"}

#: The speckle states' optics when ``rig.diffraction`` is on (:mod:`scenes.optics.mtf`).
OPTICS_VERSION = "diffraction-otf/1"

#: The specimen path's version (tessellation, paint layout, truth maps): a change that alters a specimen
#: dataset's images or truth files gets a new one, so stored datasets are not reused across it.
SPECIMEN_RENDER_VERSION = "mesh-specimen/4"

#: Which sections of a scenario change the images of each dataset it renders.
DATASET_SECTIONS = {
    "dic2d": {"images": ("experiment", "seed", "render", "speckle", "image2d")},
    "rigid_motion": {"calibration": ("seed", "rig", "render", "target", "lens"),
                     "states": ("seed", "rig", "render", "speckle", "motion", "drift", "illumination", "lens")},
    "specimen": {"states": ("seed", "rig", "render", "speckle", "specimen")},
}


def dataset_parts(scenario: Scenario) -> dict[str, tuple[str, dict]]:
    """The datasets a scenario renders: ``{part: (hash, the content it is the hash of)}``."""
    # defaults left out: a new parameter keeps old hashes; the renderers enter as their tags (below) only
    data = to_dict(_renderers_as_default(scenario), skip_defaults=True)
    out = {}
    for part, sections in DATASET_SECTIONS[scenario.experiment].items():
        content = {"experiment": scenario.experiment, "part": part, "schema": SCHEMA_VERSION,
                   **{s: data[s] for s in sections if s in data}}
        if part == "calibration":
            # which renderer made the board images (the exact renderer's views differ from Monte-Carlo ones)
            content["board_renderer"] = BOARD_RENDERER_TAGS[scenario.render.board_renderer]
        if part == "states":
            content["speckle_renderer"] = SPECKLE_RENDERER_TAGS[scenario.render.speckle_renderer]
            if scenario.rig.diffraction:        # a default-on field: datasets rendered before it were not diffracted
                content["optics"] = OPTICS_VERSION
        if scenario.experiment == "specimen" and "specimen" in content:
            # the file's content, not where it lies
            content["specimen"] = {**content["specimen"], "mesh": Path(scenario.specimen.mesh).name}
            content["specimen_file_sha256"] = file_sha256(scenario.specimen.mesh)
            content["specimen_renderer"] = SPECIMEN_RENDER_VERSION
            if scenario.rig.calibration:
                content["rig"] = {**content.get("rig", {}), "calibration": Path(scenario.rig.calibration).name}
                content["rig_calibration_sha256"] = file_sha256(scenario.rig.calibration)
        out[part] = (hash_of(content), content)
    return out


def optics_of(scenario: Scenario, pixel_pitch_mm: float):
    """The true rig's optics (:class:`scenes.optics.mtf.Optics`): its lens' diffraction at ``rig.f_number`` on pixels
    of ``pixel_pitch_mm`` (the rig's, at its scale), or ideal optics with ``rig.diffraction = false``."""
    from scenes.optics.mtf import Optics

    rig = scenario.rig
    return Optics(f_number=rig.f_number if rig.diffraction else None, wavelength_nm=rig.wavelength_nm,
                  pixel_pitch_mm=pixel_pitch_mm, fill_factor=rig.pixel_fill_factor)


def file_sha256(path: str) -> str | None:
    """SHA-256 of a file's bytes (None where it does not exist: the renderer then names the missing file)."""
    import hashlib
    from pathlib import Path

    p = Path(path)
    if not path or not p.is_file():
        return None
    digest = hashlib.sha256()
    with open(p, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def with_specimen_paths(scenario: Scenario, base_dir) -> Scenario:
    """The scenario with its specimen file (and rig calibration file) made absolute, relative to ``base_dir`` (the
    scenario file's folder)."""
    from dataclasses import replace
    from pathlib import Path

    mesh, cal = scenario.specimen.mesh, scenario.rig.calibration
    if mesh and not Path(mesh).is_absolute():
        scenario = replace(scenario, specimen=replace(scenario.specimen, mesh=str((Path(base_dir) / mesh).resolve())))
    if cal and not Path(cal).is_absolute():
        scenario = replace(scenario, rig=replace(scenario.rig, calibration=str((Path(base_dir) / cal).resolve())))
    return scenario


def _renderers_as_default(scenario: Scenario) -> Scenario:
    """The scenario with its renderer choices at their defaults: hashes carry the renderers as tags instead, so a
    scenario pinned to Mitsuba hashes as it did before the choices existed."""
    from dataclasses import replace

    defaults = RenderConfig()
    return replace(scenario, render=replace(scenario.render, board_renderer=defaults.board_renderer,
                                            speckle_renderer=defaults.speckle_renderer))


def renderer_tags(scenario: Scenario) -> dict:
    """The renderers other than Mitsuba a scenario's datasets are made with (empty for Mitsuba-only or 2-D
    scenarios): a case measured on other images is another case."""
    if scenario.experiment == "specimen":
        return {"speckle_renderer": SPECKLE_RENDERER_TAGS[scenario.render.speckle_renderer]}
    if scenario.experiment != "rigid_motion":
        return {}
    tags = {"board_renderer": BOARD_RENDERER_TAGS[scenario.render.board_renderer],
            "speckle_renderer": SPECKLE_RENDERER_TAGS[scenario.render.speckle_renderer]}
    return {k: v for k, v in tags.items() if v != "mitsuba"}


def case_hash(scenario: Scenario, instrument: Instrument) -> str:
    """Hash of one measured case: the scenario, the instrument and the renderers that made its images (a case
    rendered with Mitsuba only keeps the hash it had before the deterministic renderers existed)."""
    content = {"scenario": content_hash(_renderers_as_default(scenario)), "instrument": content_hash(instrument)}
    tags = renderer_tags(scenario)
    if tags:
        content["renderers"] = tags
    return hash_of(content)
