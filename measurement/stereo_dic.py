"""Stereo-DIC: match, triangulate and difference, following the paper's strategy (§3).

Every image is correlated to the LEFT REFERENCE image: left-ref -> right-ref gives the reference shape,
left-ref -> left-def and left-ref -> right-def give each deformed state. Points of interest live on the left
reference image, so a point's identity (its material point) is the same in every state.

The left/right match has a large disparity and a perspective distortion (stereo angle ~23 deg, different
sensor tilts), so its seeds come from feature matches: SIFT key points matched with Lowe's ratio test, outliers
removed with a RANSAC fundamental matrix, then a local affine fit of the matches around each seed node gives
the initial first-order shape; the second-order shape function absorbs the rest. No manual seed is needed.

Displacements are ``U = X_def - X_ref`` in the left camera frame (mm); ``D = |U|`` is the paper's displacement
magnitude.

Sanity: matches that do not fit the calibration are not returned as plausible numbers. A reference shape or a
state whose median triangulation residual exceeds :data:`MAX_MEDIAN_RESIDUAL_PX` (left and right images
swapped, cameras in the wrong order, a calibration of another rig), or whose measured fraction is below
:data:`MIN_MEASURED_FRACTION`, or with no point triangulated at all, raises :class:`StereoQualityError`.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from measurement.camera import ScheimpflugCamera
from measurement.dic import DICResult, DICSettings, PoiGrid, ReferenceCache, Seed, Status, correlate, poi_grid
from measurement.dic.correlate import PreparedImage, prepare_image, subset_min_std
from measurement.dic.guide import band_regions
from measurement.dic.initial import translation_parameters, zncc_search
from measurement.dic.roi import AutoRoi, AutoRoiReport, expand_result, flag_inconsistent, texture_grid
from measurement.speckle_quality import NoiseModel
from measurement.stereo import triangulate
from measurement.uncertainty.match import (FLAG_NONE, FLAG_RESIDUAL, FLAG_SATURATED, MatchUncertainty, ReferenceSubsets,
                                           interpolation_noise_gain, match_uncertainty, noise_from_residuals,
                                           reference_subsets)
from measurement.uncertainty.bias import bias_bound_px
from measurement.uncertainty.stereo import (shape_bias_bound_mm, shape_covariance_mm2, state_bias_bound_mm,
                                            state_covariances_mm2, triangulation_sensitivity)

#: Default matching settings for stereo: the paper's 65 px subset (it quotes 64) and step 5, second order.
STEREO_DIC_SETTINGS = DICSettings(subset_size=65, step=5, order=2, min_zncc=0.8)


#: A reference shape or state whose median triangulation residual exceeds this (px) is refused. Right matches
#: triangulate to a few hundredths of a pixel; swapped left/right images gave 1.45 px.
MAX_MEDIAN_RESIDUAL_PX = 0.5
#: A reference shape (of its POIs) or a state (of the reference's triangulated points) measuring less than this
#: fraction is refused.
MIN_MEASURED_FRACTION = 0.5


class StereoMatchError(ValueError):
    """A stereo match could not be started (no features, no seeds)."""


class StereoQualityError(StereoMatchError):
    """The matches do not fit the calibration (median triangulation residual too large) or too few points were
    measured. ``quality`` holds the figures."""

    def __init__(self, message: str, quality: "StereoQuality"):
        super().__init__(message)
        self.quality = quality


@dataclass(frozen=True)
class StereoQuality:
    """Triangulation figures of a reference shape or a state.

    Attributes
    ----------
    points : int
        Points that could be measured: every POI for the reference shape, the reference's triangulated points
        for a deformed state.
    measured : int
        Points measured (matched and triangulated).
    median_residual_px, p95_residual_px : float
        Median and 95th percentile of the triangulation residual over the measured points, px (NaN if none).
    """

    points: int
    measured: int
    median_residual_px: float
    p95_residual_px: float

    @property
    def measured_fraction(self) -> float:
        return self.measured / self.points if self.points else 0.0


def stereo_quality(residual_px: np.ndarray, measured: np.ndarray, points: int | None = None) -> StereoQuality:
    """:class:`StereoQuality` of per-point residuals over the ``measured`` mask (of ``points``, default all)."""
    measured = np.asarray(measured, dtype=bool)
    r = np.asarray(residual_px, dtype=np.float64)[measured]
    r = r[np.isfinite(r)]
    median, p95 = (float(np.median(r)), float(np.percentile(r, 95))) if r.size else (float("nan"), float("nan"))
    return StereoQuality(int(measured.size if points is None else points), int(measured.sum()), median, p95)


def check_thresholds(max_median_residual_px: float | None, min_measured_fraction: float | None) -> None:
    """ValueError unless the residual threshold is a finite number > 0 and the fraction one in [0, 1] (or None)."""
    if max_median_residual_px is not None and not (np.isfinite(max_median_residual_px) and max_median_residual_px > 0):
        raise ValueError(f"max_median_residual_px must be a finite number > 0 (or None), "
                         f"got {max_median_residual_px!r}")
    if min_measured_fraction is not None and not (np.isfinite(min_measured_fraction)
                                                  and 0 <= min_measured_fraction <= 1):
        raise ValueError(f"min_measured_fraction must be in [0, 1] (or None), got {min_measured_fraction!r}")


def check_stereo_quality(quality: StereoQuality, what: str, *,
                         max_median_residual_px: float | None = MAX_MEDIAN_RESIDUAL_PX,
                         min_measured_fraction: float | None = MIN_MEASURED_FRACTION) -> None:
    """Raise :class:`StereoQualityError` saying what is likely wrong unless ``quality`` passes both thresholds.

    No point measured always fails; ``None`` switches a threshold off.
    """
    check_thresholds(max_median_residual_px, min_measured_fraction)
    problems = []
    if quality.measured == 0:
        problems.append(f"no point of {quality.points} was triangulated")
    elif min_measured_fraction is not None and quality.measured_fraction < min_measured_fraction:
        problems.append(f"only {quality.measured} of {quality.points} points ({quality.measured_fraction:.0%}) were "
                        f"measured, fewer than {min_measured_fraction:.0%}")
    residual_bad = (quality.measured > 0 and max_median_residual_px is not None
                    and not quality.median_residual_px <= max_median_residual_px)
    if residual_bad:
        problems.append(f"the median triangulation residual is {quality.median_residual_px:.3g} px (95th percentile "
                        f"{quality.p95_residual_px:.3g} px), above {max_median_residual_px:g} px")
    if not problems:
        return
    if residual_bad:
        likely = ("the matched pixels do not fit the calibration's geometry: the left and right images are likely "
                  "swapped, or the calibration's cameras are in the wrong order, or the calibration belongs to "
                  "another rig or set-up (it must be of these cameras, in this position)")
    elif quality.measured == 0 or quality.measured_fraction < 0.05:
        likely = ("the images may not show the same specimen (left and right swapped, images of another rig or "
                  "state, a wrong calibration), or the region of interest misses the specimen")
    else:
        likely = ("the region of interest may reach beyond the specimen or the part both cameras see (limit it "
                  "to the specimen), or the images are swapped, or the calibration is wrong")
    raise StereoQualityError(f"{what}: {'; '.join(problems)}. Likely cause: {likely}.", quality)


@dataclass(frozen=True)
class FeatureMatches:
    """Inlier feature matches between two images.

    Attributes
    ----------
    reference_xy, target_xy : ndarray, shape (K, 2)
        Matched key-point positions (x = column, y = row), px.
    """

    reference_xy: np.ndarray
    target_xy: np.ndarray


def _as_uint8(image: np.ndarray) -> np.ndarray:
    """SIFT's 8-bit input: the one conversion of :func:`measurement.image_io.to_uint8` (scaled by the data's
    0.1-99.9 percentiles, so 12-bit data in 16 bits and floats in [0, 1] keep 256 levels; uint8 as it is)."""
    from measurement.image_io import to_uint8

    return to_uint8(image)


@dataclass(frozen=True)
class Features:
    """SIFT key points of one image: positions (K, 2) px and descriptors (K, 128)."""

    xy: np.ndarray
    descriptors: np.ndarray | None


def detect_features(image: np.ndarray, max_features: int = 8000) -> Features:
    """SIFT key points and descriptors of a grey image.

    Seeds need matches good to a pixel or so, and the affine fit averages many of them: above ~1.5 MP the
    detection runs on the half-size image (4x less work) and positions are mapped back.
    """
    image8 = _as_uint8(image)
    factor = 2.0 if image8.size > 1_500_000 else 1.0
    if factor != 1.0:
        image8 = cv2.resize(image8, None, fx=1 / factor, fy=1 / factor, interpolation=cv2.INTER_AREA)
    keypoints, descriptors = cv2.SIFT_create(nfeatures=max_features).detectAndCompute(image8, None)
    # INTER_AREA by 2 maps pixel centre x to (x + 0.5) / 2 - 0.5
    xy = (np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2) + 0.5) * factor - 0.5
    return Features(xy, descriptors)


def match_features(reference: np.ndarray | Features, target: np.ndarray, ratio: float = 0.75,
                   ransac_px: float = 1.0, name: str = "target") -> FeatureMatches:
    """SIFT matches between two grey images, filtered by the ratio test and a RANSAC fundamental matrix.

    ``reference`` may be given as its :class:`Features` (a sequence matches one reference many times).

    Raises
    ------
    StereoMatchError
        When fewer than 8 matches survive (no common texture, or no overlap): ``name`` says which image.
    """
    ref = reference if isinstance(reference, Features) else detect_features(reference)
    tgt = detect_features(target)
    if ref.descriptors is None or tgt.descriptors is None or len(ref.xy) < 8 or len(tgt.xy) < 8:
        raise StereoMatchError(f"too few features to match the reference to the {name} image "
                               f"({len(ref.xy)} and {len(tgt.xy)})")
    matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 5}, {"checks": 64})
    pairs = matcher.knnMatch(ref.descriptors, tgt.descriptors, k=2)
    good = [m for m, *rest in pairs if rest and m.distance < ratio * rest[0].distance]
    if len(good) < 8:
        raise StereoMatchError(f"only {len(good)} feature matches between the reference and the {name} image: "
                               "do the images overlap?")
    ref_xy = ref.xy[[m.queryIdx for m in good]]
    tgt_xy = tgt.xy[[m.trainIdx for m in good]]
    _, inliers = cv2.findFundamentalMat(ref_xy, tgt_xy, cv2.FM_RANSAC, ransac_px, 0.999)
    if inliers is None or int(inliers.sum()) < 8:
        raise StereoMatchError(f"feature matches to the {name} image are inconsistent (no epipolar geometry found)")
    keep = inliers.ravel().astype(bool)
    return FeatureMatches(ref_xy[keep], tgt_xy[keep])


def affine_seed(matches: FeatureMatches, x: int, y: int, radius_px: float, min_matches: int = 8) -> Seed | None:
    """First-order guess at POI (x, y) from the feature matches within ``radius_px`` (least-squares affine).

    Returns None when fewer than ``min_matches`` lie within the radius or they are degenerate (collinear).
    """
    d = matches.reference_xy - np.array([x, y], dtype=np.float64)
    near = np.hypot(d[:, 0], d[:, 1]) <= radius_px
    if near.sum() < min_matches:
        return None
    design = np.column_stack([np.ones(near.sum()), d[near]])
    if np.linalg.matrix_rank(design) < 3:
        return None
    target = matches.target_xy[near] - np.array([x, y], dtype=np.float64)
    coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)   # rows: offset, d/dx, d/dy
    residual = target - design @ coefficients
    rms = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    p = translation_parameters(coefficients[0, 0], coefficients[0, 1])
    p[1] = coefficients[1, 0] - 1.0   # ux
    p[2] = coefficients[2, 0]         # uy
    p[7] = coefficients[1, 1]         # vx
    p[8] = coefficients[2, 1] - 1.0   # vy
    # Score: a seed whose local affine fits its matches well is tried first.
    return Seed(int(x), int(y), p, zncc=-rms)


def feature_seeds(matches: FeatureMatches, grid: PoiGrid, regions: int, per_region: int = 6,
                  radius_px: float | None = None) -> list[Seed]:
    """Seeds from feature matches: up to ``per_region`` nodes per propagation band, nearest its centre first."""
    radius_px = radius_px or max(3.0 * grid.subset_size, 100.0)
    region = band_regions(grid.shape, regions)
    seeds = []
    for region_id in range(int(region.max()) + 1):
        rows, cols = np.nonzero(grid.active & (region == region_id))
        if rows.size == 0:
            continue
        order = np.argsort((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2, kind="stable")
        found = 0
        for k in order[:: max(1, rows.size // 64)]:
            seed = affine_seed(matches, int(grid.x[rows[k], cols[k]]), int(grid.y[rows[k], cols[k]]), radius_px)
            if seed is not None:
                seeds.append(seed)
                found += 1
                if found >= per_region:
                    break
    return seeds


def correlate_with_features(reference: np.ndarray | PreparedImage, target: np.ndarray, settings: DICSettings,
                            grid: PoiGrid, name: str = "target",
                            reference_features: Features | None = None,
                            matches: FeatureMatches | None = None,
                            reference_cache: ReferenceCache | None = None) -> DICResult:
    """DIC of ``reference`` -> ``target`` over ``grid``, seeded by feature matches (any disparity/rotation).

    ``reference`` may be prepared once (:func:`measurement.dic.correlate.prepare_image`) and its features detected
    once (:func:`detect_features`) for a whole sequence; ``matches`` (from :func:`match_features`) skips the
    matching; ``reference_cache`` keeps the reference side of IC-GN between matches (see
    :func:`measurement.dic.correlate`).
    """
    values = reference.values if isinstance(reference, PreparedImage) else reference
    if matches is None:
        matches = match_features(reference_features if reference_features is not None else values, target,
                                 name=name)
    seeds = feature_seeds(matches, grid, settings.regions)
    if not seeds:
        raise StereoMatchError(f"no seed could be placed for the {name} image: too few feature matches inside "
                               "the region of interest")
    return correlate(reference, target, settings, grid=grid, seeds=seeds, reference_cache=reference_cache)


#: A warm-started match must converge at least this share of the points the previous state's match converged;
#: below it the state is matched again from feature seeds (a jump the warm seeds could not follow).
WARM_START_MIN_SHARE = 0.98


def _position_keys(x, y) -> np.ndarray:
    """One int64 per pixel position (x, y >= 0, below 2^31)."""
    return np.asarray(x, dtype=np.int64) * (1 << 32) + np.asarray(y, dtype=np.int64)


def sequence_seeds(reference: np.ndarray, target: np.ndarray, grid: PoiGrid, previous: DICResult,
                   settings: DICSettings, per_region: int = 2, tries_per_region: int = 6,
                   min_zncc: float = 0.5) -> list[Seed]:
    """Seeds for matching ``target`` when the previous image of the sequence was matched (``previous``).

    In each propagation band, at the nodes the previous match converged nearest the band's centre, the subset is
    searched (ZNCC over +- ``settings.search_radius_px`` around the previous displacement, no rotation), and the
    seed takes the found translation with the previous match's shape parameters (its strain, rotation, and the
    other camera's foreshortening). A few template searches replace a feature detection and matching of the whole
    image. Returns [] when no node of ``grid`` converged in ``previous`` or no search reaches ``min_zncc``.
    """
    ok = previous.status == Status.CONVERGED
    if not ok.any():
        return []
    # previous points by position (one int64 key per node, sorted): the grids may differ (an automatic ROI keeps a
    # subset of the nodes)
    key_prev = _position_keys(previous.x[ok], previous.y[ok])
    sorter = np.argsort(key_prev, kind="stable")
    sorted_keys = key_prev[sorter]
    params = previous.parameters[ok]
    region = band_regions(grid.shape, settings.regions)
    half = grid.half
    seeds = []
    for region_id in range(int(region.max()) + 1):
        rows, cols = np.nonzero(grid.active & (region == region_id))
        xs, ys = grid.x[rows, cols].astype(np.int64), grid.y[rows, cols].astype(np.int64)
        keys = _position_keys(xs, ys)
        at = np.minimum(np.searchsorted(sorted_keys, keys), sorted_keys.size - 1)
        known = sorted_keys[at] == keys
        if not known.any():
            continue
        xs, ys, index = xs[known], ys[known], sorter[at[known]]
        xy = np.column_stack([xs, ys]).astype(np.float64)
        order = np.argsort(np.sum((xy - xy.mean(axis=0)) ** 2, axis=1), kind="stable")
        found = 0
        for k in order[:: max(1, order.size // 64)][:tries_per_region]:
            x, y = int(xs[k]), int(ys[k])
            p = params[index[k]].copy()
            seed = zncc_search(reference, target, x, y, half, int(settings.search_radius_px), (p[0], p[6]))
            if seed is None or not seed.zncc >= min_zncc:
                continue
            p[0], p[6] = seed.parameters[0], seed.parameters[6]
            seeds.append(Seed(x, y, p, seed.zncc))
            found += 1
            if found >= per_region:
                break
    return seeds


# ---------------------------------------------------------------------------------------------------------

@dataclass
class StereoShape:
    """The reference shape: left-ref -> right-ref match and the triangulated points.

    Attributes
    ----------
    x, y : ndarray of int64, shape (N,)
        POIs on the left reference image, px.
    right_match : DICResult
        Left-ref -> right-ref DIC.
    X_mm : ndarray, shape (N, 3)
        Points in the left camera frame, mm (NaN where invalid).
    residual_px : ndarray, shape (N,)
        RMS reprojection residual of the triangulation, px.
    valid : ndarray of bool, shape (N,)
    """

    x: np.ndarray
    y: np.ndarray
    right_match: DICResult
    X_mm: np.ndarray
    residual_px: np.ndarray
    valid: np.ndarray
    grid: PoiGrid = field(repr=False)
    reference: PreparedImage | None = field(default=None, repr=False)    # left reference, prepared once
    reference_features: Features | None = field(default=None, repr=False)
    quality: StereoQuality | None = None      # residual statistics and measured fraction
    #: With an automatic ROI (:mod:`measurement.dic.roi`): its settings, the textured nodes of ``grid`` that are
    #: correlated, the noise the texture test used (grey) and what it flagged; None without.
    auto_roi: AutoRoi | None = None
    measure_grid: PoiGrid | None = field(default=None, repr=False)
    noise_sigma_grey: float | None = None
    auto_roi_report: AutoRoiReport | None = None
    #: Random uncertainty (:mod:`measurement.uncertainty`): the left reference subsets' Hessians, the stereo
    #: match's uncertainty, the covariance of X_mm (N, 3, 3) mm^2, and the noise models used ("left", "right");
    #: None when the shape was measured with ``uncertainty=False``.
    subsets: ReferenceSubsets | None = field(default=None, repr=False)
    match_uncertainty: MatchUncertainty | None = field(default=None, repr=False)
    cov_X_mm2: np.ndarray | None = field(default=None, repr=False)
    noise: dict | None = None
    #: Bound on every match's interpolation bias (N, 2) px (the left reference subset's,
    #: :mod:`measurement.uncertainty.bias`), and what it bounds in X_mm (N, 3) mm; systematic, not in the sigma.
    bias_bound_px: np.ndarray | None = field(default=None, repr=False)
    bias_bound_X_mm: np.ndarray | None = field(default=None, repr=False)
    #: The calibration's (systematic, correlated) part of the covariance of X_mm (N, 3, 3) mm^2
    #: (:func:`calibration_uncertainty`); None until computed, NaN for a calibration without covariance.
    calibration_cov_X_mm2: np.ndarray | None = field(default=None, repr=False)
    calibration_G_ref: np.ndarray | None = field(default=None, repr=False)
    #: Triangulation sensitivity at the reference points (N, 3, 4) mm/px (:mod:`measurement.uncertainty.stereo`).
    G_ref: np.ndarray | None = field(default=None, repr=False)
    #: The right reference image, prepared as the stereo match sampled it: the stereo match's uncertainty needs
    #: what the right camera sees (its blur and scale, :func:`measurement.uncertainty.match.cross_hessians`).
    right_reference: PreparedImage | None = field(default=None, repr=False)
    #: IC-GN's reference side of every node of the correlated grid (:class:`measurement.dic.ReferenceCache`),
    #: filled by the stereo match and read by both matches of every state.
    reference_cache: ReferenceCache | None = field(default=None, repr=False)


@dataclass
class StereoState:
    """One deformed state measured against the reference shape (arrays over the same N points).

    Attributes
    ----------
    X_mm, U_mm : ndarray, shape (N, 3)
        Deformed position and displacement ``X_def - X_ref`` in the left camera frame, mm.
    D_mm : ndarray, shape (N,)
        Displacement magnitude ``|U|``, mm.
    residual_px : ndarray, shape (N,)
        Triangulation residual of the deformed state, px.
    zncc : ndarray, shape (N,)
        Lowest ZNCC of the three matches the point relies on.
    status : ndarray of int8, shape (N,)
        :class:`Status` of the first match that failed for this point, CONVERGED if all three did (a point that
        converged everywhere but could not be triangulated is DIVERGED).
    left_match, right_match : DICResult
        Left-ref -> left-def and left-ref -> right-def DIC.
    """

    X_mm: np.ndarray
    U_mm: np.ndarray
    D_mm: np.ndarray
    residual_px: np.ndarray
    zncc: np.ndarray
    status: np.ndarray
    left_match: DICResult
    right_match: DICResult
    quality: StereoQuality | None = None      # residual statistics, measured fraction of the reference's points
    auto_roi_report: AutoRoiReport | None = None    # what the automatic ROI flagged, if the shape has one
    #: Random uncertainty (None when the shape has none): covariance of X_mm and of U_mm (N, 3, 3) mm^2, the two
    #: temporal matches' uncertainties, and ``flag`` (N,) int8: 0 trusted, else the first flag of the three
    #: matches (:data:`measurement.uncertainty.match.FLAG_NAMES`).
    cov_X_mm2: np.ndarray | None = field(default=None, repr=False)
    cov_U_mm2: np.ndarray | None = field(default=None, repr=False)
    left_uncertainty: MatchUncertainty | None = field(default=None, repr=False)
    right_uncertainty: MatchUncertainty | None = field(default=None, repr=False)
    flag: np.ndarray | None = field(default=None, repr=False)
    #: Bounds on the interpolation bias of X_mm and U_mm (N, 3) mm (:mod:`measurement.uncertainty.bias`).
    bias_bound_X_mm: np.ndarray | None = field(default=None, repr=False)
    bias_bound_U_mm: np.ndarray | None = field(default=None, repr=False)
    #: The calibration's part of the covariance of X_mm and U_mm (N, 3, 3) mm^2 (:func:`calibration_uncertainty`).
    calibration_cov_X_mm2: np.ndarray | None = field(default=None, repr=False)
    calibration_cov_U_mm2: np.ndarray | None = field(default=None, repr=False)
    #: The calibration's sigma of the mean of U over the measured points (3,) mm: the part common to the field.
    calibration_sigma_mean_U_mm: np.ndarray | None = field(default=None, repr=False)
    #: Which seeds each match kept: {"left": ..., "right": ...}, "features" or "previous state" (a warm start
    #: from the state measured before it, see :func:`measure_state`).
    seeded_by: dict | None = None

    @property
    def valid(self) -> np.ndarray:
        return self.status == Status.CONVERGED


def _check_rig_images(left: ScheimpflugCamera, right: ScheimpflugCamera, images: dict[str, np.ndarray]) -> None:
    for name, image in images.items():
        camera = left if name.startswith("left") else right
        shape = np.asarray(image).shape
        if len(shape) != 2:
            raise ValueError(f"{name} image must be 2-D grey, got shape {shape}")
        if (shape[1], shape[0]) != (camera.width, camera.height):
            raise ValueError(f"{name} image is {shape[1]} x {shape[0]} px but the calibration is for "
                             f"{camera.width} x {camera.height} px")


def reference_shape(left: ScheimpflugCamera, right: ScheimpflugCamera, R_right_from_left, T_right_from_left_mm,
                    left_ref: np.ndarray, right_ref: np.ndarray, settings: DICSettings = STEREO_DIC_SETTINGS, *,
                    roi=None, mask=None, max_median_residual_px: float | None = MAX_MEDIAN_RESIDUAL_PX,
                    min_measured_fraction: float | None = MIN_MEASURED_FRACTION,
                    auto_roi: AutoRoi | None = None, noise: dict | None = None,
                    uncertainty: bool = True) -> StereoShape:
    """Match left-ref -> right-ref (feature seeds) and triangulate the reference shape.

    ``auto_roi`` (default None: off) correlates only the grid nodes whose left-reference subset passes
    :func:`measurement.dic.roi.texture_mask` (the others are LOW_TEXTURE) and flags the matches that fail
    :func:`measurement.dic.roi.consistency_flags` INCONSISTENT; the measured fraction is then of the textured
    nodes. :func:`measure_state` does the same for every state of this shape.

    ``uncertainty`` (default True) also computes every point's random uncertainty
    (:mod:`measurement.uncertainty.match`, :mod:`measurement.uncertainty.stereo`) with the cameras' noise models
    ``noise = {"left": NoiseModel, "right": NoiseModel}`` (from static pairs:
    :func:`measurement.speckle_quality.noise_from_static_pair`); without them the noise is fitted to the stereo
    match's own residuals (both cameras alike; it errs high where the shape function misfits).

    Raises
    ------
    StereoMatchError
        No features or seeds; :class:`StereoQualityError` when the shape fails :func:`check_stereo_quality`
        (median residual above ``max_median_residual_px``, fewer than ``min_measured_fraction`` of the POIs
        triangulated, or none).
    """
    check_thresholds(max_median_residual_px, min_measured_fraction)
    _check_rig_images(left, right, {"left reference": left_ref, "right reference": right_ref})
    grid = poi_grid(np.asarray(left_ref).shape, settings.subset_size, settings.step, roi=roi, mask=mask,
                    interpolation=settings.interpolation)
    prepared = prepare_image(left_ref, settings.interpolation, True, "left reference", settings.lowpass_sigma_px)
    features = detect_features(left_ref)
    measure_grid, sigma, report = grid, None, None
    if auto_roi is not None:
        measure_grid, sigma = texture_grid(left_ref, grid, auto_roi)
        if not measure_grid.active.any():
            raise StereoMatchError(f"auto ROI: none of the {grid.count} points of interest of the left reference "
                                   f"has enough texture (noise {sigma:.3g} grey)")
    cache = ReferenceCache.for_grid(prepared.values, measure_grid, settings,
                                    subset_min_std(settings, prepared.values))
    match = correlate_with_features(prepared, right_ref, settings, measure_grid, name="right reference",
                                    reference_features=features, reference_cache=cache)
    if auto_roi is not None:
        match, flags = flag_inconsistent(expand_result(match, grid), auto_roi, left_ref, sigma)
        report = AutoRoiReport(grid.count, grid.count - measure_grid.count,
                               int(np.count_nonzero(match.status == Status.INCONSISTENT)), sigma, flags.counts())
    pixels_left = np.column_stack([match.x, match.y]).astype(np.float64)
    pixels_right = pixels_left + np.column_stack([match.u, match.v])
    tri = triangulate(left, right, R_right_from_left, T_right_from_left_mm, pixels_left, pixels_right)
    valid = tri.valid & match.converged
    quality = stereo_quality(tri.reprojection_error_px, valid, None if auto_roi is None else measure_grid.count)
    check_stereo_quality(quality, "reference shape (left reference -> right reference)",
                         max_median_residual_px=max_median_residual_px, min_measured_fraction=min_measured_fraction)
    shape = StereoShape(match.x, match.y, match, tri.X_left_mm, tri.reprojection_error_px, valid, grid, prepared,
                        features, quality, auto_roi, None if auto_roi is None else measure_grid, sigma, report)
    shape.reference_cache = cache
    shape.right_reference = prepare_image(right_ref, settings.interpolation, False, "right reference",
                                          settings.lowpass_sigma_px)
    if uncertainty:
        shape_uncertainty(shape, left, right, R_right_from_left, T_right_from_left_mm, settings, noise)
    return shape


def _check_noise(noise) -> dict | None:
    if noise is None:
        return None
    if not isinstance(noise, dict) or set(noise) != {"left", "right"} or \
            not all(isinstance(v, NoiseModel) for v in noise.values()):
        raise ValueError("noise must be {'left': NoiseModel, 'right': NoiseModel} (or None: estimated from the "
                         f"matches), got {noise!r}")
    return noise


def shape_uncertainty(shape: StereoShape, left, right, R, T, settings: DICSettings, noise: dict | None = None) -> None:
    """Fill (or refill, e.g. once a static pair has given the cameras' noise) the shape's uncertainty fields (see
    :class:`StereoShape`) with ``noise = {"left": NoiseModel, "right": NoiseModel}``, or with the noise fitted to
    the stereo match's residuals (None). Every state measured afterwards uses them."""
    noise = _check_noise(noise)
    values = shape.reference.values
    half = settings.subset_size // 2
    box = (int(shape.x.min()) - half, int(shape.y.min()) - half, int(shape.x.max()) + half + 1,
           int(shape.y.max()) + half + 1)
    gains = interpolation_noise_gain(values, shape.reference.spline.degree, box=box)
    if noise is None:
        # both cameras alike: the stereo match's residuals hold the noise of both images
        model = noise_from_residuals(values, shape.x, shape.y, shape.right_match,
                                     interpolation=settings.interpolation, gains=gains)
        noise = {"left": model, "right": model}
    subsets = reference_subsets(shape.reference, shape.x, shape.y, settings.subset_size, settings.order,
                                noise["left"], settings.interpolation, gains=gains)
    # the stereo match's cross terms, kept: the right camera's states reuse them where they strain little
    unc = match_uncertainty(subsets, shape.right_match, noise["right"], target=shape.right_reference,
                            keep_cross=shape.right_reference is not None)
    G = triangulation_sensitivity(left, right, R, T, shape.X_mm)
    shape.subsets, shape.match_uncertainty, shape.noise = subsets, unc, noise
    shape.cov_X_mm2 = shape_covariance_mm2(G, unc.cov_reference_px2, unc.cov_target_px2)
    shape.G_ref = G                           # every state's propagation starts from it
    if shape.bias_bound_px is None:          # the reference's texture alone: the same whatever the noise
        shape.bias_bound_px = bias_bound_px(values, shape.x, shape.y, settings.subset_size, settings.interpolation,
                                            order=settings.order)
    shape.bias_bound_X_mm = shape_bias_bound_mm(G, shape.bias_bound_px)


def measure_state(left: ScheimpflugCamera, right: ScheimpflugCamera, R_right_from_left, T_right_from_left_mm,
                  shape: StereoShape, left_ref: np.ndarray, left_def: np.ndarray, right_def: np.ndarray,
                  settings: DICSettings = STEREO_DIC_SETTINGS, *,
                  max_median_residual_px: float | None = MAX_MEDIAN_RESIDUAL_PX,
                  min_measured_fraction: float | None = MIN_MEASURED_FRACTION,
                  name: str = "deformed state", previous: StereoState | None = None) -> StereoState:
    """Match left-ref -> left-def and left-ref -> right-def, triangulate, and difference with the reference.

    ``previous``: the state measured just before in the same sequence (same shape). Its matches seed this
    state's (:func:`sequence_seeds`: a template search per band instead of feature matching of the whole images);
    where that converges fewer than :data:`WARM_START_MIN_SHARE` of the points the previous match did, the match
    is made again from feature seeds. ``StereoState.seeded_by`` says which seeds each match kept.

    Raises
    ------
    StereoMatchError
        No features or seeds; :class:`StereoQualityError` (naming ``name``) when the state fails
        :func:`check_stereo_quality`: its median residual is above ``max_median_residual_px`` or it measured
        fewer than ``min_measured_fraction`` of the reference's triangulated points (or none).
    """
    check_thresholds(max_median_residual_px, min_measured_fraction)
    _check_rig_images(left, right, {"left deformed": left_def, "right deformed": right_def})
    reference = shape.reference if shape.reference is not None else left_ref
    grid = shape.measure_grid if shape.measure_grid is not None else shape.grid
    cache = shape.reference_cache if shape.reference is not None else None
    matched = {}
    if previous is not None:
        values = reference.values if isinstance(reference, PreparedImage) else np.asarray(reference, dtype=np.float64)
        for side, target, before in (("left", left_def, previous.left_match), ("right", right_def,
                                                                                previous.right_match)):
            seeds = sequence_seeds(values, np.asarray(target), grid, before, settings)
            if not seeds:
                continue
            result = correlate(reference, target, settings, grid=grid, seeds=seeds, reference_cache=cache)
            if np.count_nonzero(result.converged) >= WARM_START_MIN_SHARE * np.count_nonzero(before.converged):
                matched[side] = result
    missing = [(side, target, f"{side} deformed") for side, target in (("left", left_def), ("right", right_def))
               if side not in matched]
    if missing:
        features = shape.reference_features if shape.reference_features is not None else detect_features(left_ref)
        # The feature matchings (OpenCV, single-threaded for the most part) run side by side.
        with ThreadPoolExecutor(len(missing)) as pool:
            feature_matches = list(pool.map(lambda item: match_features(features, item[1], name=item[2]), missing))
        for (side, target, label), matches in zip(missing, feature_matches):
            matched[side] = correlate_with_features(reference, target, settings, grid, name=label, matches=matches,
                                                    reference_cache=cache)
    left_match, right_match = matched["left"], matched["right"]
    seeded_by = {side: "features" if side in {m[0] for m in missing} else "previous state"
                 for side in ("left", "right")}
    reasons = {}
    if shape.auto_roi is not None:
        left_match, left_flags = flag_inconsistent(expand_result(left_match, shape.grid), shape.auto_roi, left_ref,
                                                   shape.noise_sigma_grey)
        right_match, right_flags = flag_inconsistent(expand_result(right_match, shape.grid), shape.auto_roi,
                                                     left_ref, shape.noise_sigma_grey)
        for name_, n in (*left_flags.counts().items(), *right_flags.counts().items()):
            reasons[name_] = reasons.get(name_, 0) + n
    base = np.column_stack([shape.x, shape.y]).astype(np.float64)
    tri = triangulate(left, right, R_right_from_left, T_right_from_left_mm,
                      base + np.column_stack([left_match.u, left_match.v]),
                      base + np.column_stack([right_match.u, right_match.v]))
    status = np.full(shape.x.size, int(Status.CONVERGED), dtype=np.int8)
    for match in (right_match, left_match, shape.right_match):
        failed = match.status != Status.CONVERGED
        status[failed] = match.status[failed]
    status[(status == Status.CONVERGED) & ~(tri.valid & shape.valid)] = int(Status.DIVERGED)
    ok = status == Status.CONVERGED
    X = np.where(ok[:, None], tri.X_left_mm, np.nan)
    U = X - shape.X_mm
    zncc = np.fmin(np.fmin(shape.right_match.zncc, left_match.zncc), right_match.zncc)
    residual = np.where(ok, tri.reprojection_error_px, np.nan)
    quality = stereo_quality(residual, ok, int(np.count_nonzero(shape.valid)))
    check_stereo_quality(quality, name, max_median_residual_px=max_median_residual_px,
                         min_measured_fraction=min_measured_fraction)
    report = None
    if shape.auto_roi is not None:
        low = shape.auto_roi_report.low_texture if shape.auto_roi_report is not None else 0
        report = AutoRoiReport(shape.x.size, low, int(np.count_nonzero(status == Status.INCONSISTENT)),
                               shape.noise_sigma_grey, reasons)
    state = StereoState(X, U, np.linalg.norm(U, axis=1), residual, np.where(ok, zncc, np.nan), status, left_match,
                        right_match, quality, report, seeded_by=seeded_by)
    if shape.subsets is not None:
        _state_uncertainty(state, shape, left, right, R_right_from_left, T_right_from_left_mm, left_def, right_def)
    return state


def _state_uncertainty(state: StereoState, shape: StereoShape, left, right, R, T, left_def, right_def) -> None:
    """Fill the state's uncertainty fields (see :class:`StereoState`): each match's cross terms from its own
    target where it strains away from what they were known for (the left reference's own view, the stereo
    match's), reused elsewhere."""
    su = shape.match_uncertainty
    lu = match_uncertainty(shape.subsets, state.left_match, shape.noise["left"], target=left_def,
                           like=shape.subsets)
    with_cross = su.cross is not None
    ru = match_uncertainty(shape.subsets, state.right_match, shape.noise["right"],
                           target=right_def if with_cross else None, like=su if with_cross else None)
    G_ref = shape.G_ref if shape.G_ref is not None else triangulation_sensitivity(left, right, R, T, shape.X_mm)
    G_def = triangulation_sensitivity(left, right, R, T, state.X_mm)
    cov_X, cov_U = state_covariances_mm2(G_ref, G_def, su.cov_reference_px2, su.cov_target_px2,
                                         lu.cov_target_px2, ru.cov_target_px2,
                                         factors=(su.reference_factor, lu.reference_factor, ru.reference_factor))
    flag = np.full(state.X_mm.shape[0], FLAG_NONE, dtype=np.int8)
    for unc in (ru, lu, su):
        hit = (flag == FLAG_NONE) & ((unc.flag == FLAG_RESIDUAL) | (unc.flag == FLAG_SATURATED))
        flag[hit] = unc.flag[hit]
    state.cov_X_mm2, state.cov_U_mm2 = cov_X, cov_U
    state.left_uncertainty, state.right_uncertainty, state.flag = lu, ru, flag
    if shape.bias_bound_px is not None:
        state.bias_bound_X_mm, state.bias_bound_U_mm = state_bias_bound_mm(G_ref, G_def, shape.bias_bound_px)


#: Points at which :func:`calibration_uncertainty` differentiates the triangulation (the rest interpolated).
CALIBRATION_SAMPLE_POINTS = 400


def _sensitivity_everywhere(rig, x, y, pixels_left, pixels_right, names, max_points: int) -> np.ndarray:
    """d X / d theta (N, 3, k) at every point: exact at up to ``max_points`` points spread over the grid, linearly
    interpolated over the left image between them (the calibration's effect varies smoothly over the field)."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    from measurement.uncertainty.calibration import calibration_sensitivity

    ok = np.all(np.isfinite(pixels_left), axis=1) & np.all(np.isfinite(pixels_right), axis=1)
    idx = np.flatnonzero(ok)
    out = np.full((x.size, 3, len(names)), np.nan)
    if idx.size == 0:
        return out
    sample = idx if idx.size <= max_points else idx[np.linspace(0, idx.size - 1, max_points).round().astype(int)]
    G = calibration_sensitivity(rig, pixels_left[sample], pixels_right[sample], names)
    good = np.all(np.isfinite(G.reshape(len(sample), -1)), axis=1)
    sample, G = sample[good], G[good]
    if sample.size < 4:
        out[sample] = G
        return out
    xy = np.column_stack([x[sample], y[sample]]).astype(np.float64)
    flat = G.reshape(len(sample), -1)
    query = np.column_stack([x[idx], y[idx]]).astype(np.float64)
    values = LinearNDInterpolator(xy, flat)(query)
    outside = ~np.all(np.isfinite(values), axis=1)
    if outside.any():
        values[outside] = NearestNDInterpolator(xy, flat)(query[outside])
    out[idx] = values.reshape(idx.size, 3, len(names))
    return out


def calibration_uncertainty(shape: StereoShape, state: StereoState | None, rig, *,
                            max_points: int = CALIBRATION_SAMPLE_POINTS) -> None:
    """Fill the calibration's part of the covariance (:mod:`measurement.uncertainty.calibration`): of the shape's
    X (``state=None``) or of a state's X and U (``G_U = G_def - G_ref``: the same calibration error acts on both
    states). ``rig``: a CalibratedRig or StereoCalibration; without a covariance every value is NaN (and a warning
    says the calibration part is unknown, once).
    """
    from measurement.uncertainty.calibration import rig_covariance

    cov, names = rig_covariance(rig)
    n = shape.x.size
    if cov is None:
        nan = np.full((n, 3, 3), np.nan)
        if state is None:
            shape.calibration_cov_X_mm2 = nan
        else:
            state.calibration_cov_X_mm2, state.calibration_cov_U_mm2 = nan, nan.copy()
            state.calibration_sigma_mean_U_mm = np.full(3, np.nan)
        return
    x, y = shape.x.astype(np.float64), shape.y.astype(np.float64)
    base = np.column_stack([x, y])
    rm = shape.right_match
    if shape.calibration_G_ref is None:
        shape.calibration_G_ref = _sensitivity_everywhere(rig, x, y, base, base + np.column_stack([rm.u, rm.v]),
                                                          names, max_points)
    G_ref = shape.calibration_G_ref

    def propagate(G):
        return np.einsum("nik,kl,njl->nij", G, cov, G)

    if state is None:
        shape.calibration_cov_X_mm2 = propagate(G_ref)
        return
    lm, rmd = state.left_match, state.right_match
    G_def = _sensitivity_everywhere(rig, x, y, base + np.column_stack([lm.u, lm.v]),
                                    base + np.column_stack([rmd.u, rmd.v]), names, max_points)
    state.calibration_cov_X_mm2 = propagate(G_def)
    G_U = G_def - G_ref
    state.calibration_cov_U_mm2 = propagate(G_U)
    # the calibration error shifts the whole field alike as much as this: the mean's sigma (common mode)
    used = state.valid & np.all(np.isfinite(G_U.reshape(n, -1)), axis=1)
    G_mean = G_U[used].mean(axis=0) if used.any() else np.full(G_U.shape[1:], np.nan)
    state.calibration_sigma_mean_U_mm = np.sqrt(np.clip(np.diag(G_mean @ cov @ G_mean.T), 0.0, None))
