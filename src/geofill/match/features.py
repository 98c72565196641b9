"""Local features and descriptor matching for the matching ladder: SIFT and affine-simulated SIFT
(ASIFT) keypoints with RootSIFT descriptors, exact ratio-test matching, and matching guided by a
first estimate of the epipolar geometry."""

from __future__ import annotations

import ctypes
import functools
import hashlib
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Features:
    """Keypoint positions (N, 2) float64 in pixels of the image they were detected on, and their
    RootSIFT descriptors (N, 128) float32, unit L2 norm."""

    pts: np.ndarray
    desc: np.ndarray

    def __len__(self) -> int:
        return int(self.pts.shape[0])


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """HxWx3 RGB (uint8 or float in [0, 1]) -> HxW uint8 grey."""
    if image.dtype != np.uint8:
        image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image


def keypoint_mask(hole: np.ndarray, margin_px: float) -> np.ndarray:
    """uint8 detection mask (255 = allowed) excluding the hole dilated by ``margin_px``."""
    allowed = np.where(hole, 0, 255).astype(np.uint8)
    r = int(np.ceil(margin_px))
    if r > 0:
        allowed = cv2.erode(allowed, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return allowed


def _root_sift(kps, desc) -> Features:
    if desc is None or len(kps) == 0:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))
    # RootSIFT (Arandjelovic & Zisserman 2012): L1-normalise, square-root; Euclidean distance on it
    # is the Hellinger kernel, which matches better than raw SIFT at no cost.
    desc = np.sqrt(desc / (np.abs(desc).sum(axis=1, keepdims=True) + 1e-7)).astype(np.float32)
    return Features(np.array([kp.pt for kp in kps], dtype=np.float64), desc)


def downsized(
    gray: np.ndarray, mask: np.ndarray | None, max_side: int
) -> tuple[np.ndarray, np.ndarray | None, float]:
    """``gray`` (and its detection ``mask``) area-resized to a long side of at most ``max_side``
    (0 = as is), with the factor ``f``: a pixel ``p`` there is ``(p + 0.5) / f - 0.5`` here."""
    f = min(1.0, max_side / max(gray.shape)) if max_side else 1.0
    if f < 1.0:
        gray = cv2.resize(gray, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
        if mask is not None:
            mask = cv2.resize(mask, gray.shape[::-1], interpolation=cv2.INTER_NEAREST)
    return gray, mask, f


def detect_sift(
    gray: np.ndarray, max_features: int, mask: np.ndarray | None = None, max_side: int = 0
) -> Features:
    """SIFT keypoints (the ``max_features`` strongest; 0 = all) with RootSIFT descriptors, detected
    on ``gray`` downsized to a long side of at most ``max_side`` (0 = as is); positions in
    ``gray``'s pixels."""
    small, mask, f = downsized(gray, mask, max_side)
    kps, desc = cv2.SIFT_create(nfeatures=max_features).detectAndCompute(small, mask)
    feats = _root_sift(kps, desc)
    return feats if f == 1.0 else Features((feats.pts + 0.5) / f - 0.5, feats.desc)


#: Target features kept for the other references of a fill (and the next fills of the same target).
_CACHED_TARGETS = 2
_targets: OrderedDict[tuple, Future] = OrderedDict()
_targets_lock = threading.Lock()


def _digest(a: np.ndarray | None) -> bytes:
    if a is None:
        return b""
    return hashlib.blake2b(np.ascontiguousarray(a).data, digest_size=16).digest() + repr(a.shape).encode()


def detect_sift_pair(
    grays: tuple[np.ndarray, np.ndarray],
    max_features: int,
    masks: tuple[np.ndarray | None, np.ndarray | None],
    max_side: int = 0,
) -> tuple[Features, Features]:
    """:func:`detect_sift` on a target and a source at once, one thread each: OpenCV releases the
    GIL and SIFT barely uses its own threads (berlin, 1280x960 both: 1.25 s one after the other,
    0.74 s at once on 2 cores). The results are the same as one after the other.

    The target's features are computed once per target content, mask and budget: the other
    references of a fill (matched in other threads) wait for the first one's instead of detecting
    them again."""
    key = (_digest(grays[0]), _digest(masks[0]), max_features, max_side)
    with _targets_lock:
        pending = _targets.get(key)
        first = pending is None
        if first:
            pending = _targets[key] = Future()
            while len(_targets) > _CACHED_TARGETS:
                _targets.popitem(last=False)
        _targets.move_to_end(key)
    if not first:
        source = detect_sift(grays[1], max_features, masks[1], max_side)
        release_free_memory()
        return pending.result(), source
    try:
        with ThreadPoolExecutor(2, thread_name_prefix="sift") as pool:
            target, source = pool.map(detect_sift, grays, (max_features,) * 2, masks, (max_side,) * 2)
    except BaseException as exc:
        with _targets_lock:
            _targets.pop(key, None)
        pending.set_exception(exc)
        raise
    pending.set_result(target)
    release_free_memory()
    return target, source


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    try:  # the C library is among the process's own symbols
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):  # not glibc (macOS, Windows, musl): nothing to release
        return None


def release_free_memory() -> None:
    """Give the memory malloc holds free back to the system (glibc's ``malloc_trim``; elsewhere
    nothing). SIFT's scale spaces (~200 MB an image at 1280 px) are allocated in the worker
    threads' malloc arenas, which glibc keeps after the threads free them: at 4K a fill's peak
    RSS was 0.84-0.94 GB with that memory held through the later stages, 0.73-0.75 GB with it
    released (the peak is then SIFT's own)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


def asift_views(max_tilt: int) -> list[tuple[float, float]]:
    """(tilt, roll in degrees) of ASIFT's simulated views, lowest tilt first: tilts sqrt(2)^k for
    k < ``max_tilt``, rolls every 72/t degrees over half a turn (Morel & Yu 2009; OpenCV's
    ``AffineFeature`` defaults)."""
    views = [(1.0, 0.0)]
    for k in range(1, max_tilt):
        t = float(np.sqrt(2.0) ** k)
        views += [(t, float(r)) for r in np.arange(0.0, 180.0, 72.0 / t)]
    return views


def detect_asift(
    grays: tuple[np.ndarray, np.ndarray],
    masks: tuple[np.ndarray | None, np.ndarray | None],
    max_tilt: int,
    max_side: int,
    features_per_view: int,
    max_features: int,
    deadline: float,
) -> tuple[Features, Features, int]:
    """ASIFT features of two images (OpenCV's ``AffineFeature`` around SIFT) at a long side of
    at most ``max_side``, positions in the input images' pixels; the ``max_features`` strongest
    (by detector response) of each image are kept.

    The simulated views are run one at a time, alternating between the images, so that when
    ``deadline`` (``time.perf_counter()``) passes both images stop after the same views: what was
    found is kept. Returns both feature sets and the number of views used."""
    views = asift_views(max_tilt)
    per_image: list[tuple[list, list, float]] = []
    for gray, mask in zip(grays, masks, strict=True):
        gray, mask, f = downsized(gray, mask, max_side)
        per_image.append(([], [], f, gray, mask))
    detector = cv2.AffineFeature_create(cv2.SIFT_create(nfeatures=features_per_view))
    used = 0
    for tilt, roll in views:
        if used and time.perf_counter() > deadline:
            break
        detector.setViewParams([tilt], [roll])
        for kps, descs, _, gray, mask in per_image:
            k, d = detector.detectAndCompute(gray, mask)
            if d is not None and len(k):
                kps.extend(k)
                descs.append(d)
        used += 1
    out = []
    for kps, descs, f, _, _ in per_image:
        strongest = np.argsort([-kp.response for kp in kps], kind="stable")[:max_features]
        desc = np.concatenate(descs)[strongest] if descs else None
        feats = _root_sift([kps[i] for i in strongest], desc)
        out.append(Features((feats.pts + 0.5) / f - 0.5, feats.desc))
    return out[0], out[1], used


def mutual_ratio_matches(
    desc_a: np.ndarray, desc_b: np.ndarray, ratio: float, mutual: bool, allowed: np.ndarray | None = None
) -> np.ndarray:
    """(M, 2) index pairs (i in a, j in b) passing Lowe's ratio test (a->b) and, if asked, the
    mutual nearest-neighbour check. Descriptors must be L2-normalised (RootSIFT is). ``allowed``
    (bool, len(a) x len(b)) restricts the candidates of each descriptor (guided matching): the
    ratio test is then between the two best allowed candidates.

    Exact nearest neighbours from one float32 matrix product (BLAS) and two row maxima: faster
    than OpenCV's brute-force matcher on 2 cores, and exact unlike FLANN.

    >>> d = np.eye(3, dtype=np.float32)
    >>> mutual_ratio_matches(d, d[[2, 0, 1]], ratio=0.8, mutual=True).tolist()
    [[0, 1], [1, 2], [2, 0]]
    """
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    sim = np.asarray(desc_a, np.float32) @ np.asarray(desc_b, np.float32).T
    if allowed is not None:
        # Similarities lie in [0, 1] (non-negative unit descriptors): -1 is "no candidate".
        sim[~allowed] = -1.0
    rows = np.arange(len(desc_a))
    first = sim.argmax(axis=1)
    best1 = sim[rows, first]
    # Column maxima, not arg-maxima: numpy's argmax across rows is 20x slower than max.
    column_best = sim.max(axis=0) if mutual else None
    # The second best of a row is its maximum once the best is masked out (two passes over the
    # matrix instead of a partial sort of every row).
    sim[rows, first] = -np.inf
    best2 = sim.max(axis=1)
    # For unit vectors ||a - b||^2 = 2 - 2 a.b: the ratio test on distances, squared.
    d1 = np.maximum(2.0 - 2.0 * best1, 0.0)
    d2 = np.maximum(2.0 - 2.0 * best2, 0.0)
    keep = (d1 < np.float32(ratio**2) * d2) & (best1 >= 0.0)
    if mutual:
        keep &= best1 >= column_best[first]
    i = np.flatnonzero(keep)
    if mutual:
        # A tie for a column's maximum keeps its first row, as an arg-maximum would.
        i = i[np.unique(first[i], return_index=True)[1]]
        i.sort()
    return np.stack([i, first[i]], axis=1).astype(np.int64)


def epipolar_band(pts_t: np.ndarray, pts_s: np.ndarray, F: np.ndarray, band_px: float) -> np.ndarray:
    """(len(t), len(s)) bool: target point i lies within ``band_px`` of the epipolar line of
    source point j (``x_t^T F x_s = 0``)."""
    lines = np.c_[pts_s, np.ones(len(pts_s))] @ F.T  # (Ns, 3) lines in the target
    lines /= np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)[:, None]
    # float32 like the similarity matrix it masks (positions < 1e4 px: 1e-3 px resolution).
    dist = np.c_[pts_t, np.ones(len(pts_t))].astype(np.float32) @ lines.astype(np.float32).T
    return np.abs(dist) < band_px
