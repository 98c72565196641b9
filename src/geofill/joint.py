"""One registration for the target and all references (COLMAP's incremental SfM with bundle
adjustment, through pycolmap), run after the per-pair focal and pose stages whenever the ``sfm``
extra is installed and there are several references (``registration.joint``).

Every image's camera lands in one frame and the intrinsics are refined together over tracks that
span several views, which per-pair two-view geometry cannot do: on the posed multi-reference sets
it registers every reference to 0.17-0.72 deg and the focal to 1-1.4 %, where the per-pair stages
err by up to 20 deg and -44..+16 % (``benchmarks/studies/joint_registration.py``). Where it
registers nothing (the Kinect living room) or leaves out the target or a reference, that
reference keeps the per-pair path; without the extra every reference does.

In two halves: :func:`extract` (the images and their features in COLMAP's database) needs no focal
length, so the fill runs it while the pairs are matched; :func:`register` (matching, mapping) starts
from the pairs' focal estimate.
"""

from __future__ import annotations

import contextlib
import hashlib
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from . import extras
from .camera import Intrinsics, make_pose
from .config import GeometryConfig, IntrinsicsConfig
from .focal import FocalEstimate, prior_sigma
from .match import Matches
from .match.features import Features
from .pose import PoseEstimate, normalise, parallax_deg
from .utils.resolution import resize_long, resize_mask_any

#: Long side (px, as COLMAP sees the images) under which its SIFT starts from the upsampled octave:
#: needed at 320 px (rendered views); at 624 px (the Kinect living room) it cost 0.9 s of a 2-s fill
#: for a change within noise.
UPSAMPLE_BELOW_PX = 480

FAST_PNG = [cv2.IMWRITE_PNG_COMPRESSION, 1]  # written once, read once: size does not matter


@dataclass(frozen=True)
class JointCamera:
    """One reference as the joint registration left it (input pixels)."""

    T: np.ndarray  # 4x4 source->target, COLMAP's scale (shared by all references of the model)
    focal_target: float
    focal_source: float


def available() -> bool:
    """Whether pycolmap (the ``sfm`` extra) is installed."""
    return extras.available("pycolmap")


@dataclass(frozen=True)
class JointDatabase:
    """COLMAP's database of a joint registration with every image's features (:func:`extract`),
    waiting for the focal lengths to start from (:func:`register`). Its folder is removed once
    registered."""

    folder: tempfile.TemporaryDirectory
    names: tuple[str, ...]  # target.png, then each source's name in COLMAP's database
    shrink: tuple[float, ...]  # the factor each image was resized by for COLMAP

    @property
    def path(self) -> Path:
        return Path(self.folder.name)


def extract(
    target: np.ndarray,
    hole: np.ndarray,
    sources: Sequence[np.ndarray],
    one_camera: bool,
    max_features: int = 2048,
    max_side: int = 0,
    features: Sequence[Features] | None = None,
) -> JointDatabase:
    """The first half of :func:`register_jointly`, which needs no focal length: it can run while
    the pairs are still matched."""
    import pycolmap

    if features is not None:
        max_side = 0
    shrink = [_shrink(img.shape, max_side) for img in [target, *sources]]
    images_in = [resize_long(img, max_side) if max_side else img for img in [target, *sources]]
    hole = resize_mask_any(hole, max_side) if max_side else hole
    folder = tempfile.TemporaryDirectory(prefix="geofill-joint-")
    work = Path(folder.name)
    images = work / "images"
    images.mkdir()
    # Named by content, not by position: COLMAP's incremental mapping depends on the images'
    # order, and the fill must not depend on the order the references are given in.
    rank = np.argsort([hashlib.sha256(img.tobytes()).hexdigest() for img in sources], kind="stable")
    names = ["target.png"] + [""] * len(sources)
    for position, k in enumerate(rank):
        names[1 + k] = f"source{position}.png"
    for name, img in zip(names, images_in, strict=True):
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(images / name), grey, FAST_PNG)
    same = len({img.shape[:2] for img in images_in}) == 1 and one_camera
    reader = pycolmap.ImageReaderOptions()
    # geofill models no lens distortion: a radial term fitted here and then dropped cost
    # COLMAP's poses half their agreement with a pair's own matches on fox upper.
    reader.camera_model = "SIMPLE_PINHOLE"
    mode = pycolmap.CameraMode.SINGLE if same else pycolmap.CameraMode.PER_IMAGE
    db_path = work / "db.db"
    with _quiet():
        pycolmap.set_random_seed(0)
        if features is None:
            _extract_features(db_path, images, names, images_in, hole, mode, reader, max_features)
        else:
            _import_features(db_path, images, names, features, mode, reader)
    return JointDatabase(folder, tuple(names), tuple(shrink))


def register(
    db: JointDatabase, focal_target: float, focal_sources: Sequence[float], threads: int = 1
) -> list[JointCamera | None]:
    """The second half of :func:`register_jointly`: COLMAP's matching and mapping from these focal
    lengths (px of the images given to :func:`extract`)."""
    import pycolmap

    focals = [
        f * k for f, k in zip([float(focal_target), *map(float, focal_sources)], db.shrink, strict=True)
    ]
    work, names = db.path, db.names
    db_path = work / "db.db"
    try:
        with _quiet():
            pycolmap.set_random_seed(0)
            _seed_focals(db_path, names, focals)
            verification = pycolmap.TwoViewGeometryOptions()
            verification.ransac.random_seed = 0
            matching = pycolmap.FeatureMatchingOptions()
            # Each pair's matching and verification is seeded on its own, so threads do not change the
            # result (5 runs identical on fox upper); 2 threads: 0.50 -> 0.31 s on the tower.
            matching.num_threads = threads
            pycolmap.match_exhaustive(db_path, matching_options=matching, verification_options=verification)
            mapping = pycolmap.IncrementalPipelineOptions()
            mapping.num_threads = 1  # no run-to-run differences from the order threads finish in (~0.3 s)
            mapping.random_seed = mapping.mapper.random_seed = mapping.triangulation.random_seed = 0
            mapping.mapper.num_threads = 1
            maps = pycolmap.incremental_mapping(db_path, work / "images", work / "sparse", options=mapping)
    finally:
        db.folder.cleanup()
    none: list[JointCamera | None] = [None] * (len(names) - 1)
    if not maps:
        return none
    rec = max(maps.values(), key=lambda r: r.num_reg_images())
    by_name = {img.name: img for img in rec.images.values()}
    if "target.png" not in by_name:
        return none

    def world_to_cam(img) -> np.ndarray:
        m = np.eye(4)
        m[:3] = img.cam_from_world().matrix()
        return m

    t = by_name["target.png"]
    w_t = world_to_cam(t)
    f_t = float(rec.cameras[t.camera_id].params[0]) / db.shrink[0]
    out = []
    for name, k in zip(names[1:], db.shrink[1:], strict=True):
        img = by_name.get(name)
        if img is None:
            out.append(None)
            continue
        T = w_t @ np.linalg.inv(world_to_cam(img))
        out.append(JointCamera(T, f_t, float(rec.cameras[img.camera_id].params[0]) / k))
    return out


def register_jointly(
    target: np.ndarray,
    hole: np.ndarray,
    sources: Sequence[np.ndarray],
    focal_target: float,
    focal_sources: Sequence[float],
    max_features: int = 2048,
    max_side: int = 0,
    features: Sequence[Features] | None = None,
    threads: int = 1,
) -> list[JointCamera | None]:
    """COLMAP's registration of ``target`` (8-bit grey or RGB; its ``hole`` masked out for the
    features) and every source: one entry per source, None where the target or that source is not
    in the largest model. Each camera starts from the given focal (px of these images; COLMAP's
    own start, 1.2 x the long side, let the rendered 375-px scenes drift to x2.2 with the
    translation flipped). One shared camera when every image has the same size and focal.
    Deterministic: fixed RANSAC seeds, mapping on one thread. ``max_side`` > 0: COLMAP
    sees the images shrunk to that long side (the focal lengths come back in the given images' px).
    ``features``: the target's (outside the hole) and each source's SIFT keypoints in these images'
    px, used instead of COLMAP's own detector (``max_features`` and ``max_side`` do not apply).
    ``threads``: for the matching (the rest runs on one)."""
    one = len({float(focal_target), *map(float, focal_sources)}) == 1
    db = extract(target, hole, sources, one, max_features, max_side, features)
    return register(db, focal_target, focal_sources, threads)


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """COLMAP's step-by-step log and its "no model" errors silenced: the stage line says it."""
    import pycolmap

    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = level


def _shrink(shape: tuple[int, ...], max_side: int) -> float:
    """The factor :func:`resize_long` scales an image of ``shape`` by (1 when ``max_side`` is 0)."""
    if not max_side or max(shape[:2]) <= max_side:
        return 1.0
    h, w = shape[:2]
    return max(round(w * max_side / max(h, w)), 1) / w


def _extract_features(
    db_path: Path,
    images: Path,
    names: Sequence[str],
    pixels: Sequence[np.ndarray],
    hole: np.ndarray,
    mode,
    reader,
    max_features: int,
) -> None:
    """COLMAP's database with the images and its own SIFT features, none in the target's hole."""
    import pycolmap

    masks = images.parent / "masks"
    masks.mkdir()
    for name, img in zip(names, pixels, strict=True):
        keep = ~hole if name == "target.png" else np.ones(img.shape[:2], bool)
        cv2.imwrite(str(masks / f"{name}.png"), keep.astype(np.uint8) * 255, FAST_PNG)  # 0 = ignored
    reader.mask_path = str(masks)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.sift.max_num_features = max_features
    # No upsampled octave (a third of the time, same poses) unless the images are small: on the
    # 320-px rendered view sets COLMAP's focal came out 8 % short from the few features of octave 0.
    small = max(max(img.shape[:2]) for img in pixels) < UPSAMPLE_BELOW_PX
    extraction.sift.first_octave = -1 if small else 0
    # One thread: with its threads 1 fill in 5 still differed run to run, and one extraction thread
    # measured no slower on 2 busy cores (3.36 vs 3.58 s, fox upper).
    extraction.num_threads = 1
    pycolmap.extract_features(
        db_path, images, camera_mode=mode, reader_options=reader, extraction_options=extraction
    )


def _import_features(
    db_path: Path, images: Path, names: Sequence[str], features: Sequence[Features], mode, reader
) -> None:
    """COLMAP's database with the images and the given keypoints as its SIFT features."""
    import pycolmap

    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, images, mode, list(names), reader)
    db = pycolmap.Database.open(db_path)
    try:
        for img in db.read_all_images():
            f = features[list(names).index(img.name)]
            # COLMAP puts pixel centres at +0.5 and stores SIFT as bytes of 512 x the unit descriptor.
            db.write_keypoints(img.image_id, (f.pts + 0.5).astype(np.float32))
            desc = np.clip(np.rint(f.desc * 512.0), 0, 255).astype(np.uint8)
            db.write_descriptors(
                img.image_id, pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, desc)
            )
    finally:
        db.close()


def _seed_focals(db_path: Path, names: Sequence[str], focals: Sequence[float]) -> None:
    """Give each image's camera in COLMAP's database its focal as a known prior."""
    import pycolmap

    db = pycolmap.Database.open(db_path)
    try:
        focal_of = {}
        for img in db.read_all_images():
            focal_of[img.camera_id] = focals[list(names).index(img.name)]
        for cam in db.read_all_cameras():
            params = np.array(cam.params, dtype=float)
            params[0] = focal_of[cam.camera_id]
            cam.params = params
            cam.has_prior_focal_length = True
            db.update_camera(cam)
    finally:
        db.close()


def joint_focal(cam: JointCamera, K_t: Intrinsics, K_s: Intrinsics, target_width: int, source_width: int):
    """The focal stage's result from the joint registration (``K_t``/``K_s``: the working priors)."""
    K_t_new = replace(K_t, fx=cam.focal_target * K_t.width / target_width, origin="estimated")
    K_t_new = replace(K_t_new, fy=K_t_new.fx, rel_uncertainty=None)
    K_s_new = replace(K_s, fx=cam.focal_source * K_s.width / source_width, origin="estimated")
    K_s_new = replace(K_s_new, fy=K_s_new.fx, rel_uncertainty=None)
    return FocalEstimate(K_t_new, K_s_new, "estimated", "joint", "", K_t, K_s, [])


def prior_conflict(est: FocalEstimate, cfg: IntrinsicsConfig) -> str:
    """Why the joint registration's focal must not be used ("" when it may): a focal given by a
    flag, or one further than ``max_prior_conflict`` sigma from its prior (an EXIF focal, say:
    COLMAP never sees the EXIF, as the images reach it as PNGs)."""
    for K, prior, which in (
        (est.K_target, est.prior_target, "target"),
        (est.K_source, est.prior_source, "source"),
    ):
        sigma = prior_sigma(prior, cfg)
        if sigma == 0.0:
            return f"the {which} focal is given"
        conflict = abs(np.log(K.fx / prior.fx)) / sigma
        if conflict > cfg.max_prior_conflict:
            scale = K.fx / prior.fx
            return f"its {which} focal x{scale:.2f} contradicts the {prior.origin} prior ({conflict:.1f} sd)"
    return ""


def agreeing(T: np.ndarray, matches: Matches, K_t: Intrinsics, K_s: Intrinsics, thr_px: float) -> np.ndarray:
    """Which of ``matches`` a source->target pose ``T`` (any translation scale) and these
    intrinsics explain: within ``thr_px`` (Sampson) of its epipolar geometry and in front of both
    cameras. A pure rotation (zero translation): within ``thr_px`` of its homography."""
    R, t = T[:3, :3], T[:3, 3]
    x_s, x_t = normalise(matches.pts_source, K_s), normalise(matches.pts_target, K_t)
    focal = 0.5 * (K_t.fx + K_s.fx)
    norm = float(np.linalg.norm(t))
    h_s = np.column_stack([x_s, np.ones(len(x_s))])
    h_t = np.column_stack([x_t, np.ones(len(x_t))])
    if norm < 1e-12:
        p = h_s @ R.T
        p = p[:, :2] / np.where(np.abs(p[:, 2:]) < 1e-12, 1e-12, p[:, 2:])
        return (np.linalg.norm(p - x_t, axis=1) < thr_px / focal) & ((h_s @ R.T)[:, 2] > 0)
    t = t / norm
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    E = tx @ R
    Ex, Etx = h_s @ E.T, h_t @ E
    num = np.sum(h_t * Ex, axis=1) ** 2
    sampson = num / (Ex[:, 0] ** 2 + Ex[:, 1] ** 2 + Etx[:, 0] ** 2 + Etx[:, 1] ** 2 + 1e-300)
    close = sampson < (thr_px / focal) ** 2
    X = cv2.triangulatePoints(np.eye(3, 4), np.column_stack([R, t]), x_s.T, x_t.T)
    X = X[:3] / np.where(np.abs(X[3]) < 1e-12, 1e-12, X[3])
    front = (X[2] > 0) & ((R @ X + t[:, None])[2] > 0)
    return close & front


def joint_pose(
    cam: JointCamera, matches: Matches, K_t: Intrinsics, K_s: Intrinsics, thr_px: float, cfg: GeometryConfig
) -> PoseEstimate | None:
    """The pose stage's result from the joint registration: translation to unit norm, inliers =
    the pair's matches it explains (:func:`agreeing`). None when too few agree (then the
    per-pair pose runs)."""
    R, t = cam.T[:3, :3], cam.T[:3, 3]
    norm = float(np.linalg.norm(t))
    if norm < 1e-12 or len(matches) == 0:
        return None
    t = t / norm
    inliers = agreeing(make_pose(R, t), matches, K_t, K_s, thr_px)
    if int(inliers.sum()) < cfg.min_inliers:
        return None
    par_deg = parallax_deg(matches.pts_target[inliers], matches.pts_source[inliers], K_t, K_s, R)
    par = float(np.median(par_deg))
    if par < cfg.min_median_parallax_deg:
        reason = f"joint registration, near-pure rotation (median parallax {par:.2f} deg)"
        return PoseEstimate(make_pose(R, np.zeros(3)), inliers, "rotation_only", reason, par)
    return PoseEstimate(make_pose(R, t), inliers, "ok", "joint registration", par)
