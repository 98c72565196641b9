"""Object-removal protocols with exact ground truth, beside the restoration protocol (a hole cut
into the background and blanked).

In real use the hole shows the object being removed, and the references may show it too (it is
still there when they were taken) or show other things in front of the background (people walking
by). A method that copies what the references show into the hole then pastes the object back. Both
protocols draw such objects into real or synthetic images whose clean target is known, so the
truth is exact:

``static``
    A photo cutout (:mod:`.cutouts`) on a plane fronto-parallel to the target camera at
    :data:`DEPTH_FRACTION` of the nearest scene depth around it, drawn into the target and, through
    the plane's homography ``K_s (R + t n^T / d) K_t^-1`` under the ground-truth pose, into every
    reference: the same object seen from each camera, parallax-shifted against the background.
    Scene depth: exact on synthetic scenes, else SIFT matches triangulated with the GT pose (5th
    percentile of the points around the object); occlusion: where a reference's depth is known
    (synthetic, GT depth files) the object is drawn only where it is nearer than the scene.
    The hole is the object's silhouette in the target dilated by :data:`HOLE_DILATION_720P` px (at a
    720-px short side); the target the methods get shows the object. Needs K and pose of every
    reference.

``strangers``
    The restoration protocol's brush-stroke hole; the target shows a photo cutout there (in no
    reference), and each reference gets other cutouts (strangers) where the hole's background
    appears in it, covering a random 30-60 % (:data:`STRANGER_COVERAGE`) of that region. Where it
    appears: :func:`.scene_geometry.reference_maps` (exact on synthetic scenes, GT pose with
    triangulated depth, else a SIFT homography near the hole: an approximation).

Every random choice is seeded by (protocol, pair id, seed) through SHA-256, as the masks are.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from .cutouts import Blob, bilinear, draw, make_cutout, photo_crop, random_blob
from .masks import DEFAULT_AREA_RANGE, DEFAULT_STROKE_WIDTH_720P, PAPER_SHORT_SIDE_PX
from .pairs import Pair, PairGeometry, pair_geometry, pair_mask, stroke_width_px
from .scene_geometry import (
    ReferenceMap,
    ScenePoints,
    plane_depth_map,
    plane_homography,
    reference_maps,
    triangulated_points,
)

#: ``--protocol`` choices; ``restoration`` is the brush-stroke protocol of :mod:`.runner`.
PROTOCOLS = ("restoration", "static", "strangers")
REMOVAL_PROTOCOLS = PROTOCOLS[1:]
#: One line per removal protocol for the summary.
PROTOCOL_TEXT = {
    "static": "a planar photo cutout in front of the scene, drawn into the target and, with its "
    "GT-pose projection and occlusion, into every reference; hole = its target silhouette, dilated; "
    "the methods get the target showing it; truth = the clean target",
    "strangers": "the restoration brush-stroke hole showing a photo cutout in the target, and other "
    "cutouts covering 30-60 % of the hole's background in each reference; the methods get the "
    "target showing the cutout; truth = the clean target",
}
#: The static object's depth as a fraction of the nearest scene depth around it: drawn uniformly
#: in this range per placement tried (nearer: more parallax, more of the background behind it
#: seen by the references, but it leaves their frames sooner; nearer the background: less).
DEPTH_FRACTION = (0.5, 0.9)
#: Percentile of the triangulated depths around the object taken as the nearest scene depth
#: (robust to a few wrong points).
NEAR_PERCENTILE = 5.0
#: The static object covers this fraction of the target (drawn uniformly).
STATIC_AREA_RANGE = (0.03, 0.08)
#: Margin between the static object and the target's border (fraction of the short side).
STATIC_MARGIN = 0.05
#: The static hole is the object's silhouette dilated by this (px at a 720-px short side).
HOLE_DILATION_720P = 4.0
#: A static placement is kept when at least this fraction of the object is visible in every
#: reference (inside the image and, where the depth is known, in front of the scene).
MIN_VISIBLE = 0.8
#: Fraction of the hole's background region in a reference that its strangers cover.
STRANGER_COVERAGE = (0.3, 0.6)
#: Radius of one stranger (times the mean brush width) and the most strangers per reference.
STRANGER_RADIUS = (0.8, 1.6)
MAX_STRANGERS = 12
_TRIES = 200
_MIN_POINTS_NEAR = 8


class ProtocolSkip(Exception):
    """The protocol cannot be applied to this pair; the message says why."""


@dataclass
class RemovalCase:
    """One pair prepared for a removal protocol.

    ``pair`` is what the methods get (target and references with the objects drawn in), ``truth``
    the clean target, ``hole`` the hole, ``objects`` the object pixels the leak metric compares
    with, in the target frame: (HxWx3 uint8 image, HxW bool where it holds an object pixel).
    ``objects`` are the protocol's own (static: the object as drawn in the target; strangers: each
    reference's strangers mapped into the target), ``extra_objects`` what ``leak_all`` adds
    (static: each reference's object mapped into the target as if it were background; strangers:
    the target's own cutout)."""

    protocol: str
    pair: Pair
    truth: np.ndarray
    hole: np.ndarray
    objects: list[tuple[np.ndarray, np.ndarray]]
    extra_objects: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    stroke_width_720p: float = 0.0
    stroke_width_px: float = 0.0
    placement: StaticPlacement | None = None


def case_seed(protocol: str, pair_id: str, seed: int) -> int:
    """64-bit RNG seed of ``protocol`` on ``pair_id`` under the user's ``seed``."""
    digest = hashlib.sha256(f"geofill-removal\x00{protocol}\x00{pair_id}\x00{int(seed)}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


def is_grey(image: np.ndarray) -> bool:
    """All three channels equal (e.g. KITTI's grey frames read as RGB)."""
    return bool(np.array_equal(image[..., 0], image[..., 1]) and np.array_equal(image[..., 0], image[..., 2]))


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def hole_dilation_px(height: int, width: int) -> int:
    """:data:`HOLE_DILATION_720P` scaled to an image (at least 2 px)."""
    return max(2, round(HOLE_DILATION_720P * min(height, width) / PAPER_SHORT_SIDE_PX))


# ---------------------------------------------------------------------------------------------
# static


@dataclass
class StaticPlacement:
    """Where the static object is: ``blob`` in target pixels on the plane ``z = z_object`` of the
    target camera (``z_object = fraction * z_near``, the nearest scene depth around it), the
    plane's homography target -> each reference, the fraction of the object each reference sees,
    and how many scene points the depth came from (0: exact depth)."""

    blob: Blob
    z_near: float
    fraction: float
    homographies: list[np.ndarray]
    visible: list[float]
    n_points: int

    @property
    def z_object(self) -> float:
        return self.fraction * self.z_near

    @property
    def score(self) -> float:
        return min(self.visible) if self.visible else 0.0


def _interior(blob: Blob, n: int = 30) -> np.ndarray:
    """Points of a grid over ``blob``'s box that lie inside it (about n x n tested)."""
    x0, y0, x1, y1 = blob.bbox
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    return pts[blob.inside(pts)]


def _near_depth(blob: Blob, g: PairGeometry, points: ScenePoints | None) -> tuple[float, int] | None:
    """Nearest scene depth around ``blob`` in the target: exact (min of the depth over its box
    grown by 10 %), or the :data:`NEAR_PERCENTILE` percentile of the scene points in its box
    grown by 50 % (None with fewer than 8 there)."""
    x0, y0, x1, y1 = blob.bbox
    if g.depth_target is not None:
        h, w = g.depth_target.shape
        m = 0.1 * (x1 - x0)
        xa, xb = max(int(x0 - m), 0), min(int(np.ceil(x1 + m)), w - 1)
        ya, yb = max(int(y0 - m), 0), min(int(np.ceil(y1 + m)), h - 1)
        return float(g.depth_target[ya : yb + 1, xa : xb + 1].min()), 0
    m = 0.5 * (x1 - x0)
    uv = points.uv
    near = (uv[:, 0] >= x0 - m) & (uv[:, 0] <= x1 + m) & (uv[:, 1] >= y0 - m) & (uv[:, 1] <= y1 + m)
    if near.sum() < _MIN_POINTS_NEAR:
        return None
    return float(np.percentile(points.z[near], NEAR_PERCENTILE)), int(near.sum())


def _visible_fraction(
    pts: np.ndarray, H: np.ndarray, shape: tuple[int, ...], z_obj: float, K: np.ndarray, T: np.ndarray, depth
) -> float:
    p = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ H.T
    if np.any(p[:, 2] <= 0):
        return 0.0
    xy = p[:, :2] / p[:, 2:]
    h, w = shape[:2]
    ok = np.all((xy >= -0.5) & (xy < np.array([w, h]) - 0.5), axis=1)
    if depth is not None and ok.any():
        z_plane = plane_depth_map(K, T, z_obj, (h, w))
        ix = np.clip(np.rint(xy[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.rint(xy[:, 1]).astype(int), 0, h - 1)
        scene = depth[iy, ix]
        ok &= (scene <= 0) | (z_plane[iy, ix] < scene)
    return float(ok.mean())


def _propose(
    rng: np.random.Generator, pair: Pair, g: PairGeometry, points: ScenePoints | None
) -> StaticPlacement | None:
    h, w = pair.target.shape[:2]
    shape = random_blob(rng)
    area = rng.uniform(*STATIC_AREA_RANGE) * h * w
    blob = shape.moved(radius=np.sqrt(area / shape.mean_area))
    margin = STATIC_MARGIN * min(h, w) + blob.reach
    if 2 * margin >= min(h, w):
        return None
    blob = blob.moved(centre=(rng.uniform(margin, w - margin), rng.uniform(margin, h - margin)))
    near = _near_depth(blob, g, points)
    if near is None:
        return None
    z_near, n_points = near
    fraction = float(rng.uniform(*DEPTH_FRACTION))
    z_obj = fraction * z_near
    pts = _interior(blob)
    homographies, visible = [], []
    for k, source in enumerate(pair.sources):
        K, T = g.K_sources[k], g.T_source_to_target[k]
        H = plane_homography(g.K_target, K, T, z_obj)
        homographies.append(H)
        visible.append(_visible_fraction(pts, H, source.shape, z_obj, K, T, g.depth_source(k)))
    return StaticPlacement(blob, z_near, fraction, homographies, visible, n_points)


def static_case(pair: Pair, seed: int = 0) -> RemovalCase:
    """The ``static`` protocol on ``pair`` (see the module docstring); :class:`ProtocolSkip` when
    the pair has no K and pose for every reference or no usable placement."""
    g = pair_geometry(pair)
    if not g.posed:
        raise ProtocolSkip("static needs K of the target and K and pose of every reference (meta.json)")
    truth = pair.target
    h, w = truth.shape[:2]
    points = None
    if g.depth_target is None:
        points = triangulated_points(pair, g)
        if len(points.z) < _MIN_POINTS_NEAR:
            raise ProtocolSkip(f"only {len(points.z)} triangulated scene points")
    rng = np.random.default_rng(case_seed("static", pair.id, seed))
    best: StaticPlacement | None = None
    for _ in range(_TRIES):
        cand = _propose(rng, pair, g, points)
        if cand is not None and (best is None or cand.score > best.score):
            best = cand
        if best is not None and best.score >= MIN_VISIBLE:
            break
    if best is None:
        raise ProtocolSkip("no placement of the object with scene depth around it")
    z_obj = best.z_object
    cutout = make_cutout(rng, best.blob, grey=is_grey(truth))
    shown, alpha = draw(truth, cutout)
    r = hole_dilation_px(h, w)
    hole = cv2.dilate((alpha > 0).astype(np.uint8), _disc(r)).astype(bool)
    sources, refs, alphas = [], [], []
    c = np.array([*best.blob.centre, 1.0])
    for k, source in enumerate(pair.sources):
        K, T, H = g.K_sources[k], g.T_source_to_target[k], best.homographies[k]
        depth = g.depth_source(k)
        front = None
        if depth is not None:
            front = (depth <= 0) | (plane_depth_map(K, T, z_obj, depth.shape) < depth)
        drawn, a = draw(source, cutout, H, front)
        sources.append(drawn)
        alphas.append(a)
        at_object = H @ c
        at_background = plane_homography(g.K_target, K, T, best.z_near) @ c
        refs.append(
            {
                "visible": round(best.visible[k], 3),
                "drawn_px": round(float(a.sum())),
                "centre_px": [round(float(v), 1) for v in at_object[:2] / at_object[2]],
                "parallax_px": round(
                    float(
                        np.linalg.norm(at_object[:2] / at_object[2] - at_background[:2] / at_background[2])
                    ),
                    1,
                ),
            }
        )
    # Where a method that takes the hole for background would copy each reference's object to.
    extra = []
    revealed = np.zeros((len(sources), int(hole.sum())), bool)
    for k, m in enumerate(reference_maps(pair, g, hole, points)):
        obj, mask, covered = mapped_back(truth, hole, sources[k], alphas[k], m)
        extra.append((obj, mask))
        revealed[k, m.valid] = ~covered
        refs[k]["revealed"] = round(float(revealed[k].mean()), 4)
        refs[k]["mapping"] = m.kind
    info = {
        "depth_from": "exact scene depth" if points is None else "triangulated SIFT matches, GT pose",
        "n_points_near": best.n_points,
        "z_near": round(best.z_near, 4),
        "depth_fraction": round(best.fraction, 3),
        "z_object": round(z_obj, 4),
        "object_area": round(float(alpha.sum()) / (h * w), 4),
        "hole_area": round(float(hole.mean()), 4),
        "hole_dilation_px": r,
        "hole_revealed": round(float(np.any(revealed, axis=0).mean()), 4),
        "references": refs,
    }
    shown_pair = replace(pair, target=shown, sources=sources)
    return RemovalCase("static", shown_pair, truth, hole, [(shown, hole)], extra, info, placement=best)


def mapped_back(
    truth: np.ndarray, hole: np.ndarray, drawn: np.ndarray, alpha: np.ndarray, m: ReferenceMap
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A reference's drawn objects seen from the target through the hole's background map ``m``:
    (HxWx3 uint8: the reference ``drawn`` read bilinearly at each hole pixel's map, HxW bool: the
    hole pixels whose map lands where the objects' ``alpha`` is >= 0.5, and that test per valid
    map point in ``m``'s order). What a method copying the reference's pixels at the
    background's correspondence would paste into the hole."""
    ys, xs = np.nonzero(hole)
    at = np.flatnonzero(m.valid)
    pts = m.xy[at]
    covered = bilinear(alpha, pts[:, 0], pts[:, 1])[:, 0] >= 0.5
    obj = np.zeros_like(truth)
    obj[ys[at], xs[at]] = np.clip(np.rint(bilinear(drawn, pts[:, 0], pts[:, 1])), 0, 255).astype(np.uint8)
    mask = np.zeros_like(hole)
    mask[ys[at[covered]], xs[at[covered]]] = True
    return obj, mask, covered


# ---------------------------------------------------------------------------------------------
# strangers


def _place_strangers(
    rng: np.random.Generator, pts: np.ndarray, goal: float, radius_px: float
) -> tuple[list[Blob], float]:
    """Blobs (radius ``STRANGER_RADIUS`` x ``radius_px``) centred on points of ``pts`` (the hole's
    region in a reference) not yet covered, added until they cover ``goal`` of ``pts``; the last
    one's radius is bisected to land on ``goal``. Returns the blobs and the coverage reached."""
    covered = np.zeros(len(pts), bool)
    blobs: list[Blob] = []
    while covered.mean() < goal and len(blobs) < MAX_STRANGERS:
        free = np.flatnonzero(~covered)
        centre = pts[free[rng.integers(len(free))]]
        blob = random_blob(rng, centre, rng.uniform(*STRANGER_RADIUS) * radius_px)
        hit = blob.inside(pts)
        if (covered | hit).mean() > goal:
            lo, hi = 0.0, blob.radius
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                lo, hi = (
                    (mid, hi) if (covered | blob.moved(radius=mid).inside(pts)).mean() < goal else (lo, mid)
                )
            blob = blob.moved(radius=hi)
            hit = blob.inside(pts)
        blobs.append(blob)
        covered |= hit
    return blobs, float(covered.mean())


def strangers_case(
    pair: Pair,
    seed: int = 0,
    width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
) -> RemovalCase:
    """The ``strangers`` protocol on ``pair`` (see the module docstring): the restoration hole of
    (``seed``, ``width_720p``, ``area_range``), a cutout in the target's hole, strangers in every
    reference that sees part of the hole's background."""
    truth = pair.target
    hole = pair_mask(pair, seed, width_720p, area_range)
    grey = is_grey(truth)
    rng = np.random.default_rng(case_seed("strangers", pair.id, seed))
    ys, xs = np.nonzero(hole)
    x0, y0 = xs.min(), ys.min()
    crop = photo_crop(rng, xs.max() - x0 + 1, ys.max() - y0 + 1, grey)
    shown = truth.copy()
    shown[ys, xs] = np.clip(np.rint(crop[ys - y0, xs - x0]), 0, 255).astype(np.uint8)
    objects = []
    g = pair_geometry(pair)
    maps = reference_maps(pair, g, hole)
    width_px = stroke_width_px(pair, width_720p)
    sources, refs = [], []
    revealed = np.zeros(len(ys), bool)
    for source, m in zip(pair.sources, maps, strict=True):
        ref_info: dict[str, Any] = {
            "mapping": m.kind,
            **m.info,
            "hole_mapped": round(float(m.valid.mean()), 4),
        }
        pts = m.xy[m.valid]
        if len(pts) < max(20, 0.01 * len(m.valid)):
            ref_info.update(n_strangers=0, coverage=0.0)
            revealed |= m.valid
            sources.append(source)
            refs.append(ref_info)
            continue
        goal = float(rng.uniform(*STRANGER_COVERAGE))
        blobs, _ = _place_strangers(rng, pts, goal, width_px)
        drawn = source
        alpha_none = np.ones(source.shape[:2], np.float32)  # product of (1 - alpha_i)
        for blob in blobs:
            drawn, a = draw(drawn, make_cutout(rng, blob, grey))
            alpha_none *= 1.0 - a
        sources.append(drawn)
        obj, mask, covered = mapped_back(truth, hole, drawn, 1.0 - alpha_none, m)
        objects.append((obj, mask))
        revealed[m.valid] |= ~covered
        ref_info.update(n_strangers=len(blobs), goal=round(goal, 3), coverage=round(float(covered.mean()), 4))
        refs.append(ref_info)
    info = {
        "hole_area": round(float(hole.mean()), 4),
        "max_coverage": max((r["coverage"] for r in refs), default=0.0),
        "hole_revealed": round(float(revealed.mean()), 4),
        "references": refs,
    }
    shown_pair = replace(pair, target=shown, sources=sources)
    return RemovalCase(
        "strangers", shown_pair, truth, hole, objects, [(shown, hole)], info, float(width_720p), width_px
    )


def make_case(
    protocol: str,
    pair: Pair,
    seed: int = 0,
    width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
) -> RemovalCase:
    """``pair`` prepared for the removal ``protocol`` (``static`` or ``strangers``)."""
    if protocol == "static":
        return static_case(pair, seed)
    if protocol == "strangers":
        return strangers_case(pair, seed, width_720p, area_range)
    raise ValueError(f"not a removal protocol: {protocol!r}")
