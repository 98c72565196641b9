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

``solid`` / ``solid_plain``
    A box (:mod:`.solids`) placed in 3D in front of the scene (its nearest corner at
    :data:`SOLID_DEPTH_FRACTION` of the nearest scene depth around it, its farthest still in front
    of that depth), turned at random about the target's vertical axis and tilted a little, and
    ray-cast into the target and every reference with the GT K and poses (faces occlude each other;
    the scene hides it where a reference's depth is known): each reference sees other faces in
    other proportions. ``solid``: each face a photo crop; ``solid_plain``: one colour, each face
    shaded by its angle to a fixed light (few keypoints, as cars, bins and dice have).

``walker`` / ``walker_crowd``
    A person-shaped cutout (:class:`.solids.Figure`: head, torso, arms, legs; a photo crop or one
    colour), upright on a plane fronto-parallel to the target camera in front of the scene, that
    walks between views: in each reference it stands elsewhere on that plane (another 3D place,
    0.5-1.3 of its width to either side, another walking phase), so the references see the
    background behind it and it is elsewhere. ``walker_crowd`` adds 1-3 other passers-by in each
    reference only, standing over where the hole's background appears in it.

Holes of ``static``, ``solid``, ``walker`` (``--removal-mask``): ``brushed`` (default,
:func:`.masks.brushed_hole`: the silhouette closed, then 15-45 px beyond it at 1280 px with a
wobbly outline, as people brush) or ``tight`` (the silhouette dilated by
:data:`HOLE_DILATION_720P`). ``strangers`` keeps the brush-stroke hole; with ``brushed`` its cutout
leaves a 15-45 px margin of the hole showing the background, with ``tight`` it fills the hole.

Every case also records the *appearances* of every object (each view as given, with the object's
pixels in it) for :func:`.metrics.ghost`, which finds an object reproduced anywhere in the hole.

Every random choice is seeded by (protocol, pair id, seed) through SHA-256, as the masks are.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from .cutouts import Blob, Cutout, bilinear, draw, make_cutout, photo_crop, random_blob
from .masks import (
    DEFAULT_AREA_RANGE,
    DEFAULT_STROKE_WIDTH_720P,
    PAPER_SHORT_SIDE_PX,
    brush_margin_px,
    brushed_hole,
    brushed_interior,
)
from .pairs import Pair, PairGeometry, pair_geometry, pair_mask, stroke_width_px
from .scene_geometry import (
    ReferenceMap,
    ScenePoints,
    plane_depth_map,
    plane_homography,
    reference_maps,
    triangulated_points,
)
from .solids import Box, Figure, composite, project_points, render_box

#: ``--protocol`` choices; ``restoration`` is the brush-stroke protocol of :mod:`.runner`.
PROTOCOLS = ("restoration", "static", "solid", "solid_plain", "strangers", "walker", "walker_crowd")
REMOVAL_PROTOCOLS = PROTOCOLS[1:]
#: ``--removal-mask`` choices: how the removal hole is drawn around the object (the first is the
#: default).
REMOVAL_MASKS = ("brushed", "tight")
#: One line per removal protocol for the summary.
PROTOCOL_TEXT = {
    "static": "a planar photo cutout in front of the scene, drawn into the target and, with its "
    "GT-pose projection and occlusion, into every reference; hole = its target silhouette, dilated; "
    "the methods get the target showing it; truth = the clean target",
    "strangers": "the restoration brush-stroke hole showing a photo cutout in the target, and other "
    "cutouts covering 30-60 % of the hole's background in each reference; the methods get the "
    "target showing the cutout; truth = the clean target",
    "solid": "a box with photo-textured faces placed in 3D in front of the scene and ray-cast, with "
    "the GT poses, faces and occlusion, into the target and every reference; the methods get the "
    "target showing it; truth = the clean target",
    "solid_plain": "as solid, the box painted one colour, each face shaded by its angle to one light",
    "walker": "a person-shaped cutout (photo or one colour) in front of the scene that stands "
    "elsewhere in each reference (walking sideways on a plane facing the target camera); the methods "
    "get the target showing it; truth = the clean target",
    "walker_crowd": "as walker, and 1-3 other passers-by in each reference only, standing over where "
    "the hole's background appears in it",
}
#: How the protocols' holes are drawn (``--removal-mask``), for the summary.
MASK_TEXT = {
    "brushed": "the object's silhouette closed, then 15-45 px beyond it at a 1280-px long side "
    "(scaled), wobbly outline; the margin shows background (strangers: the cutout leaves such a "
    "margin of the stroke hole)",
    "tight": "the object's silhouette dilated by 4 px at a 720-px short side (strangers: the cutout "
    "fills the stroke hole)",
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
    (static, solid, walker: each reference's objects mapped into the target as if they were
    background; strangers: the target's own cutout). ``appearances``: every view as the methods get
    it with the HxW bool pixels where an object shows in it (for :func:`.metrics.ghost`)."""

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
    appearances: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)


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


def _check_mask(mask: str) -> None:
    if mask not in REMOVAL_MASKS:
        raise ValueError(f"unknown removal mask {mask!r}; expected one of {', '.join(REMOVAL_MASKS)}")


def _brush_rng(pair_id: str, seed: int) -> np.random.Generator:
    """The brushed margin's own random stream, so the object placed is the same under either mask."""
    return np.random.default_rng(case_seed("brush", pair_id, seed))


def removal_hole(
    silhouette: np.ndarray, mask: str, pair_id: str, seed: int
) -> tuple[np.ndarray, dict[str, Any]]:
    """The hole over an object whose HxW bool target ``silhouette`` is given, as ``mask`` draws it
    (:data:`REMOVAL_MASKS`), and how (for cases.json)."""
    _check_mask(mask)
    h, w = silhouette.shape
    if mask == "tight":
        r = hole_dilation_px(h, w)
        return cv2.dilate(silhouette.astype(np.uint8), _disc(r)).astype(bool), {"hole_dilation_px": r}
    lo, hi = brush_margin_px(h, w)
    hole = brushed_hole(silhouette, _brush_rng(pair_id, seed))
    return hole, {"brush_margin_px": [round(lo, 1), round(hi, 1)]}


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


def _near_depth(
    bbox: tuple[float, float, float, float], g: PairGeometry, points: ScenePoints | None
) -> tuple[float, int] | None:
    """Nearest scene depth around the target box ``bbox`` (x0, y0, x1, y1): exact (min of the
    depth over the box grown by 10 %), or the :data:`NEAR_PERCENTILE` percentile of the scene
    points in the box grown by 50 % (None with fewer than 8 there)."""
    x0, y0, x1, y1 = bbox
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
    near = _near_depth(blob.bbox, g, points)
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


def _posed_scene(pair: Pair, protocol: str) -> tuple[PairGeometry, ScenePoints | None]:
    """The pair's geometry and, where its depth is not exact, its triangulated scene points;
    :class:`ProtocolSkip` when ``protocol`` cannot place an object in it."""
    g = pair_geometry(pair)
    if not g.posed:
        raise ProtocolSkip(f"{protocol} needs K of the target and K and pose of every reference (meta.json)")
    points = None
    if g.depth_target is None:
        points = triangulated_points(pair, g)
        if len(points.z) < _MIN_POINTS_NEAR:
            raise ProtocolSkip(f"only {len(points.z)} triangulated scene points")
    return g, points


def _best_placement(propose: Callable[[], Any], what: str) -> Any:
    """The placement of best ``score`` among up to :data:`_TRIES` of ``propose`` (None: none
    possible), stopping at the first one every reference sees :data:`MIN_VISIBLE` of;
    :class:`ProtocolSkip` naming ``what`` when none was possible."""
    best = None
    for _ in range(_TRIES):
        cand = propose()
        if cand is not None and (best is None or cand.score > best.score):
            best = cand
        if best is not None and best.score >= MIN_VISIBLE:
            return best
    if best is None:
        raise ProtocolSkip(f"no placement of {what}")
    return best


def _object_case(
    protocol: str,
    pair: Pair,
    g: PairGeometry,
    points: ScenePoints | None,
    drawn: tuple[np.ndarray, np.ndarray, np.ndarray],
    sources: list[np.ndarray],
    alphas: list[np.ndarray],
    refs: list[dict[str, Any]],
    info: dict[str, Any],
    placement: StaticPlacement | None = None,
) -> RemovalCase:
    """The case of an object drawn into the target (``drawn``: the target showing it, its alpha,
    the hole) and into the references (``sources`` with ``alphas``, described by ``refs``): the
    references' objects mapped back (:func:`_mapped_objects`), ``info`` completed with the depth's
    origin, areas and ``revealed``, the appearances for :func:`.metrics.ghost`."""
    shown, alpha, hole = drawn
    extra, hole_revealed = _mapped_objects(pair, g, hole, points, sources, alphas, refs)
    h, w = hole.shape
    info = {
        "depth_from": "exact scene depth" if points is None else "triangulated SIFT matches, GT pose",
        **info,
        "object_area": round(float(alpha.sum()) / (h * w), 4),
        "hole_area": round(float(hole.mean()), 4),
        "hole_revealed": hole_revealed,
        "references": refs,
    }
    looks = [(shown, alpha >= 0.5), *((src, a >= 0.5) for src, a in zip(sources, alphas, strict=True))]
    shown_pair = replace(pair, target=shown, sources=sources)
    return RemovalCase(
        protocol, shown_pair, pair.target, hole, [(shown, hole)], extra, info, placement=placement,
        appearances=looks,
    )  # fmt: skip


def static_case(pair: Pair, seed: int = 0, mask: str = REMOVAL_MASKS[0]) -> RemovalCase:
    """The ``static`` protocol on ``pair`` (see the module docstring) with the hole ``mask``;
    :class:`ProtocolSkip` when the pair has no K and pose for every reference or no usable
    placement."""
    _check_mask(mask)
    g, points = _posed_scene(pair, "static")
    truth = pair.target
    rng = np.random.default_rng(case_seed("static", pair.id, seed))
    best = _best_placement(lambda: _propose(rng, pair, g, points), "the object with scene depth around it")
    z_obj = best.z_object
    cutout = make_cutout(rng, best.blob, grey=is_grey(truth))
    shown, alpha = draw(truth, cutout)
    hole, hole_info = removal_hole(alpha > 0, mask, pair.id, seed)
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
    info = {
        "n_points_near": best.n_points,
        "z_near": round(best.z_near, 4),
        "depth_fraction": round(best.fraction, 3),
        "z_object": round(z_obj, 4),
        "hole_mask": mask,
        **hole_info,
    }
    return _object_case("static", pair, g, points, (shown, alpha, hole), sources, alphas, refs, info, best)


def _mapped_objects(
    pair: Pair,
    g: PairGeometry,
    hole: np.ndarray,
    points: ScenePoints | None,
    sources: list[np.ndarray],
    alphas: list[np.ndarray],
    refs: list[dict[str, Any]],
) -> tuple[list[tuple[np.ndarray, np.ndarray]], float]:
    """Where a method that takes the hole for background would copy each reference's objects
    (``alphas`` over the drawn ``sources``) to: per reference, :func:`mapped_back` through the
    hole's background map; also the share of the hole some reference sees unhidden. Adds each
    reference's ``revealed`` share and ``mapping`` to its ``refs`` entry."""
    extra = []
    revealed = np.zeros((len(sources), int(hole.sum())), bool)
    for k, m in enumerate(reference_maps(pair, g, hole, points)):
        obj, hit, covered = mapped_back(pair.target, hole, sources[k], alphas[k], m)
        extra.append((obj, hit))
        revealed[k, m.valid] = ~covered
        refs[k]["revealed"] = round(float(revealed[k].mean()), 4)
        refs[k]["mapping"] = m.kind
    return extra, round(float(np.any(revealed, axis=0).mean()), 4)


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
    mask: str = REMOVAL_MASKS[0],
) -> RemovalCase:
    """The ``strangers`` protocol on ``pair`` (see the module docstring): the restoration hole of
    (``seed``, ``width_720p``, ``area_range``), a cutout in the target's hole (``mask`` brushed:
    leaving a 15-45 px margin of it at 1280 px; tight: all of it), strangers in every reference
    that sees part of the hole's background."""
    _check_mask(mask)
    truth = pair.target
    hole = pair_mask(pair, seed, width_720p, area_range)
    grey = is_grey(truth)
    rng = np.random.default_rng(case_seed("strangers", pair.id, seed))
    ys, xs = np.nonzero(hole)
    x0, y0 = xs.min(), ys.min()
    crop = photo_crop(rng, xs.max() - x0 + 1, ys.max() - y0 + 1, grey)
    cut = hole if mask == "tight" else brushed_interior(hole, _brush_rng(pair.id, seed))
    if not cut.any():
        raise ProtocolSkip("the stroke hole is nowhere wider than twice the brushed margin")
    cy, cx = np.nonzero(cut)
    shown = truth.copy()
    shown[cy, cx] = np.clip(np.rint(crop[cy - y0, cx - x0]), 0, 255).astype(np.uint8)
    objects = []
    g = pair_geometry(pair)
    maps = reference_maps(pair, g, hole)
    width_px = stroke_width_px(pair, width_720p)
    sources, refs = [], []
    looks = [(shown, cut)]
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
        looks.append((drawn, alpha_none <= 0.5))
        obj, hit, covered = mapped_back(truth, hole, drawn, 1.0 - alpha_none, m)
        objects.append((obj, hit))
        revealed[m.valid] |= ~covered
        ref_info.update(n_strangers=len(blobs), goal=round(goal, 3), coverage=round(float(covered.mean()), 4))
        refs.append(ref_info)
    info = {
        "hole_area": round(float(hole.mean()), 4),
        "hole_mask": mask,
        "object_area_in_hole": round(float(cut.sum() / hole.sum()), 4),
        "max_coverage": max((r["coverage"] for r in refs), default=0.0),
        "hole_revealed": round(float(revealed.mean()), 4),
        "references": refs,
    }
    shown_pair = replace(pair, target=shown, sources=sources)
    return RemovalCase(
        "strangers",
        shown_pair,
        truth,
        hole,
        objects,
        [(shown, cut)],
        info,
        float(width_720p),
        width_px,
        appearances=looks,
    )


# ---------------------------------------------------------------------------------------------
# solid


#: The box's nearest corner at this fraction of the nearest scene depth around it (drawn
#: uniformly); a placement whose farthest corner is not in front of that depth is dropped.
SOLID_DEPTH_FRACTION = (0.45, 0.8)
#: The box's extents relative to its size (drawn uniformly per axis), and its tilt about the
#: target's horizontal axis (deg, either way) after a random turn about the vertical.
SOLID_ASPECT = (0.55, 1.4)
SOLID_TILT_DEG = 20.0


def _rotation(yaw: float, tilt: float) -> np.ndarray:
    """Turn by ``yaw`` about the camera's y axis, then tilt by ``tilt`` about its x axis (rad)."""
    cy, sy, ct, st = np.cos(yaw), np.sin(yaw), np.cos(tilt), np.sin(tilt)
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rx = np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])
    return Rx @ Ry


def _view_from_target(T_source_to_target: np.ndarray) -> np.ndarray:
    return np.linalg.inv(np.asarray(T_source_to_target, dtype=np.float64))


def _points_visible(
    X: np.ndarray, K: np.ndarray, M: np.ndarray, shape: tuple[int, ...], depth: np.ndarray | None
) -> float:
    """Share of the target-frame points ``X`` a view (K, ``M`` = view_from_target) sees inside its
    frame and, where its scene ``depth`` is known, in front of the scene (self-occlusion aside)."""
    uv, z = project_points(K, M, X)
    h, w = shape[:2]
    ok = (z > 0) & np.all((uv >= -0.5) & (uv < np.array([w, h]) - 0.5), axis=1)
    if depth is not None and ok.any():
        ix = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        scene = depth[iy, ix]
        ok &= (scene <= 0) | (z < scene)
    return float(ok.mean())


@dataclass
class _BoxPlacement:
    box: Box
    z_near: float
    n_points: int
    visible: list[float]

    @property
    def score(self) -> float:
        return min(self.visible) if self.visible else 0.0


def _propose_box(
    rng: np.random.Generator, pair: Pair, g: PairGeometry, points: ScenePoints | None
) -> _BoxPlacement | None:
    h, w = pair.target.shape[:2]
    side = float(np.sqrt(rng.uniform(*STATIC_AREA_RANGE) * h * w))
    margin = STATIC_MARGIN * min(h, w) + side
    if 2 * margin >= min(h, w):
        return None
    cx, cy = rng.uniform(margin, w - margin), rng.uniform(margin, h - margin)
    near = _near_depth((cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2), g, points)
    if near is None:
        return None
    z_near, n_points = near
    z_front = float(rng.uniform(*SOLID_DEPTH_FRACTION)) * z_near
    K = np.asarray(g.K_target, np.float64)
    half = 0.5 * side * z_front / K[0, 0] * rng.uniform(*SOLID_ASPECT, size=3)
    tilt = np.radians(rng.uniform(-SOLID_TILT_DEG, SOLID_TILT_DEG))
    axes = _rotation(float(rng.uniform(0.0, 2.0 * np.pi)), float(tilt))
    ray = np.linalg.inv(K) @ [cx, cy, 1.0]
    box = Box(np.zeros(3), axes, half, ())
    dz = box.corners()[:, 2]
    box = box.moved(ray * (z_front - dz.min()))
    corners = box.corners()
    if corners[:, 2].max() >= z_near:
        return None
    uv, _ = project_points(K, np.eye(4), corners)
    lo = STATIC_MARGIN * min(h, w)
    if np.any(uv < lo) or np.any(uv > np.array([w, h]) - lo):
        return None
    X = box.surface_points()
    visible = [
        _points_visible(
            X, g.K_sources[k], _view_from_target(g.T_source_to_target[k]), src.shape, g.depth_source(k)
        )
        for k, src in enumerate(pair.sources)
    ]
    return _BoxPlacement(box, z_near, n_points, visible)


def _face_textures(
    rng: np.random.Generator, box: Box, f: float, plain: bool, grey: bool
) -> tuple[np.ndarray, ...]:
    """Six face textures: photo crops at about one texel per target pixel, or one colour."""
    if plain:
        colour = _plain_colour(rng, grey)
        return tuple(np.full((2, 2, 3), colour, np.float32) for _ in range(6))
    z = float(box.centre[2])
    out = []
    for axis in range(3):
        j, k = [a for a in range(3) if a != axis]
        tw = max(8, int(np.ceil(2 * box.half[j] * f / z)) + 2)
        th = max(8, int(np.ceil(2 * box.half[k] * f / z)) + 2)
        out += [photo_crop(rng, tw, th, grey) for _ in range(2)]
    return tuple(out)


def _plain_colour(rng: np.random.Generator, grey: bool) -> np.ndarray:
    """A random paint colour (0-255 RGB): a saturated hue, or a grey level on grey scenes."""
    if grey:
        return np.full(3, rng.uniform(40.0, 220.0), np.float32)
    hsv = np.array([[[rng.uniform(0, 180), rng.uniform(120, 230), rng.uniform(110, 230)]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def solid_case(pair: Pair, seed: int = 0, plain: bool = False, mask: str = REMOVAL_MASKS[0]) -> RemovalCase:
    """The ``solid`` (``plain``: ``solid_plain``) protocol on ``pair`` (see the module docstring)
    with the hole ``mask``; :class:`ProtocolSkip` as :func:`static_case`."""
    _check_mask(mask)
    protocol = "solid_plain" if plain else "solid"
    g, points = _posed_scene(pair, protocol)
    truth = pair.target
    h, w = truth.shape[:2]
    rng = np.random.default_rng(case_seed(protocol, pair.id, seed))
    best = _best_placement(lambda: _propose_box(rng, pair, g, points), "the box in front of the scene")
    box = replace(
        best.box, textures=_face_textures(rng, best.box, float(g.K_target[0, 0]), plain, is_grey(truth))
    )
    colour, alpha, _ = render_box(box, g.K_target, np.eye(4), (h, w), g.depth_target)
    shown = composite(truth, colour, alpha)
    hole, hole_info = removal_hole(alpha > 0, mask, pair.id, seed)
    sources, alphas, refs = [], [], []
    for k, source in enumerate(pair.sources):
        colour, a, _ = render_box(
            box,
            g.K_sources[k],
            _view_from_target(g.T_source_to_target[k]),
            source.shape[:2],
            g.depth_source(k),
        )
        sources.append(composite(source, colour, a))
        alphas.append(a)
        refs.append({"visible": round(best.visible[k], 3), "drawn_px": round(float(a.sum()))})
    info = {
        "n_points_near": best.n_points,
        "z_near": round(best.z_near, 4),
        "box_centre": [round(float(v), 6) for v in box.centre],
        "box_half_extents": [round(float(v), 6) for v in box.half],
        "box_axes": [[round(float(v), 6) for v in row] for row in box.axes],
        "hole_mask": mask,
        **hole_info,
    }
    return _object_case(protocol, pair, g, points, (shown, alpha, hole), sources, alphas, refs, info)


# ---------------------------------------------------------------------------------------------
# walker


#: The walker covers this fraction of the target (drawn uniformly); at most this fraction of the
#: target's height tall.
WALKER_AREA_RANGE = (0.02, 0.05)
WALKER_MAX_HEIGHT = 0.8
#: In each reference the walker stands this many of its widths to one side (drawn uniformly,
#: either side) on its plane: where it was in the target is background there.
WALKER_STEP = (0.5, 1.3)
#: Passers-by per reference (``walker_crowd``), and their height relative to the walker's there.
CROWD_SIZE = (1, 3)
CROWD_SCALE = (0.8, 1.2)


def _figure_area_per_height2() -> float:
    """Area of a :class:`.solids.Figure` of height 1 (counted on a fine grid)."""
    fig = Figure((0.0, 0.0), 1.0)
    x0, y0, x1, y1 = fig.bbox
    n = 400
    gx, gy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    return float(fig.inside(np.stack([gx.ravel(), gy.ravel()], 1)).mean() * (x1 - x0) * (y1 - y0))


def _figure_cutout(rng: np.random.Generator, fig: Figure, grey: bool) -> Cutout:
    """A figure dressed in a photo crop or, half the time, in one colour."""
    if rng.random() < 0.5:
        return make_cutout(rng, fig, grey)
    x0, y0, x1, y1 = fig.bbox
    size = (int(np.ceil(y1 - y0)) + 4, int(np.ceil(x1 - x0)) + 4)
    return Cutout(
        fig, np.full((*size, 3), _plain_colour(rng, grey), np.float32), (np.floor(x0) - 1, np.floor(y0) - 1)
    )


def _shifted(cutout: Cutout, fig: Figure) -> Cutout:
    """``cutout``'s dress on the figure moved to ``fig`` (its texture moves with its crown)."""
    dx, dy = fig.top[0] - cutout.blob.top[0], fig.top[1] - cutout.blob.top[1]
    return Cutout(fig, cutout.texture, (cutout.origin[0] + dx, cutout.origin[1] + dy))


@dataclass
class _WalkerPlacement:
    figure: Figure
    z_near: float
    fraction: float
    n_points: int
    steps: list[Figure]
    visible: list[float]

    @property
    def score(self) -> float:
        return min(self.visible) if self.visible else 0.0


def _propose_walker(
    rng: np.random.Generator, pair: Pair, g: PairGeometry, points: ScenePoints | None, unit_area: float
) -> _WalkerPlacement | None:
    h, w = pair.target.shape[:2]
    height = min(float(np.sqrt(rng.uniform(*WALKER_AREA_RANGE) * h * w / unit_area)), WALKER_MAX_HEIGHT * h)
    fig = Figure((0.0, 0.0), height, float(rng.uniform(-1, 1)), float(rng.uniform(0.85, 1.2)))
    x0, y0, x1, y1 = fig.bbox
    lo = STATIC_MARGIN * min(h, w)
    if x1 - x0 + 2 * lo >= w or y1 - y0 + 2 * lo >= h:
        return None
    fig = fig.moved(top=(rng.uniform(lo - x0, w - lo - x1), rng.uniform(lo - y0, h - lo - y1)))
    near = _near_depth(fig.bbox, g, points)
    if near is None:
        return None
    z_near, n_points = near
    fraction = float(rng.uniform(*DEPTH_FRACTION))
    steps, visible = [], []
    for k, source in enumerate(pair.sources):
        K, T = g.K_sources[k], g.T_source_to_target[k]
        step = float(rng.choice([-1.0, 1.0]) * rng.uniform(*WALKER_STEP) * fig.width)
        moved = fig.moved(top=(fig.top[0] + step, fig.top[1]), stride=float(rng.uniform(-1, 1)))
        H = plane_homography(g.K_target, K, T, fraction * z_near)
        steps.append(moved)
        visible.append(
            _visible_fraction(_interior(moved), H, source.shape, fraction * z_near, K, T, g.depth_source(k))
        )
    return _WalkerPlacement(fig, z_near, fraction, n_points, steps, visible)


def _passers_by(
    rng: np.random.Generator, drawn: np.ndarray, pts: np.ndarray, height: float, grey: bool
) -> tuple[np.ndarray, np.ndarray, int]:
    """1-3 figures drawn flat into a reference (``drawn``), each standing with its middle on a
    random point of ``pts`` (the hole's background there), about ``height`` tall: the image and
    the product of their (1 - alpha)."""
    none = np.ones(drawn.shape[:2], np.float32)
    n = int(rng.integers(CROWD_SIZE[0], CROWD_SIZE[1] + 1))
    for _ in range(n):
        x, y = pts[rng.integers(len(pts))]
        tall = height * float(rng.uniform(*CROWD_SCALE))
        fig = Figure(
            (float(x), float(y) - 0.5 * tall), tall, float(rng.uniform(-1, 1)), float(rng.uniform(0.85, 1.2))
        )
        drawn, a = draw(drawn, _figure_cutout(rng, fig, grey))
        none *= 1.0 - a
    return drawn, none, n


def walker_case(pair: Pair, seed: int = 0, crowd: bool = False, mask: str = REMOVAL_MASKS[0]) -> RemovalCase:
    """The ``walker`` (``crowd``: ``walker_crowd``) protocol on ``pair`` (see the module
    docstring) with the hole ``mask``; :class:`ProtocolSkip` as :func:`static_case`."""
    _check_mask(mask)
    protocol = "walker_crowd" if crowd else "walker"
    g, points = _posed_scene(pair, protocol)
    truth = pair.target
    grey = is_grey(truth)
    rng = np.random.default_rng(case_seed(protocol, pair.id, seed))
    unit_area = _figure_area_per_height2()
    best = _best_placement(
        lambda: _propose_walker(rng, pair, g, points, unit_area), "the walker with scene depth around it"
    )
    z_obj = best.fraction * best.z_near
    cutout = _figure_cutout(rng, best.figure, grey)
    shown, alpha = draw(truth, cutout)
    hole, hole_info = removal_hole(alpha > 0, mask, pair.id, seed)
    maps = reference_maps(pair, g, hole, points) if crowd else None
    sources, alphas, refs = [], [], []
    for k, source in enumerate(pair.sources):
        K, T = g.K_sources[k], g.T_source_to_target[k]
        depth = g.depth_source(k)
        front = None
        if depth is not None:
            front = (depth <= 0) | (plane_depth_map(K, T, z_obj, depth.shape) < depth)
        H = plane_homography(g.K_target, K, T, z_obj)
        moved = best.steps[k]
        drawn, a = draw(source, _shifted(cutout, moved), H, front)
        ref = {
            "visible": round(best.visible[k], 3),
            "step_px": round(moved.top[0] - best.figure.top[0], 1),
            "drawn_px": round(float(a.sum())),
        }
        if maps is not None:
            pts = maps[k].xy[maps[k].valid]
            if len(pts):
                tall = best.figure.height * float(np.sqrt(abs(np.linalg.det(H[:2, :2] / H[2, 2]))))
                drawn, none, ref["passers_by"] = _passers_by(rng, drawn, pts, tall, grey)
                a = 1.0 - (1.0 - a) * none
        sources.append(drawn)
        alphas.append(a)
        refs.append(ref)
    info = {
        "n_points_near": best.n_points,
        "z_near": round(best.z_near, 4),
        "z_object": round(z_obj, 4),
        "walker_height_px": round(best.figure.height, 1),
        "hole_mask": mask,
        **hole_info,
    }
    return _object_case(protocol, pair, g, points, (shown, alpha, hole), sources, alphas, refs, info)


def make_case(
    protocol: str,
    pair: Pair,
    seed: int = 0,
    width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
    mask: str = REMOVAL_MASKS[0],
) -> RemovalCase:
    """``pair`` prepared for the removal ``protocol`` (:data:`REMOVAL_PROTOCOLS`) with the hole
    ``mask`` (:data:`REMOVAL_MASKS`)."""
    if protocol == "static":
        return static_case(pair, seed, mask)
    if protocol in ("solid", "solid_plain"):
        return solid_case(pair, seed, protocol == "solid_plain", mask)
    if protocol in ("walker", "walker_crowd"):
        return walker_case(pair, seed, protocol == "walker_crowd", mask)
    if protocol == "strangers":
        return strangers_case(pair, seed, width_720p, area_range, mask)
    raise ValueError(f"not a removal protocol: {protocol!r}")
