"""The screen stage: what of a reference's refined render may be copied into the hole.

What the hole shows is the thing the user removes: it is used only as a negative, never as content.
A static object shows in every reference at its 3D place, and rendering a reference re-pastes it
(at the surface depth the hole's surroundings give it, so shifted by parallax). Two tests find it:

- *Located in the reference.* SIFT keypoints of the hole's content are matched to the reference
  (ratio test, mutual, consistent with the pair's epipolar geometry). With enough matches, their
  homography maps the hole's content into the reference, and the reference pixels that agree with
  it there are the object; they are not rendered. The homography also maps the hole's margin, which
  shows background, onto reference pixels that show other background (parallax), which disagree and
  stay: background revealed behind the object is used.
- *Seen again in place.* Render pixels whose patch equals the hole's own content at the same place
  (an object at the depth of its surroundings: a sign, a poster, a stain) are refused, in regions
  that reach into the hole beyond a patch's width from its border (the border shows background that
  the render rightly reproduces).

Strangers (a passer-by, a car that moved) show in a reference and not in the target. Where one
reaches beyond the hole, the render disagrees with the target around the hole; the render content
that continues it into the hole is refused, grown from there by OpenCV's watershed against the
render pixels that agree with the target. This test runs on every fill, hole blanked or not.

Reference pixels the user masked (``source_masks``) are never rendered. A hole that shows nothing
(blank or constant) refuses no object.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .composite.inpaint import mask_window
from .config import FillConfig, ScreenConfig
from .focal import FocalEstimate
from .match import Matches
from .match.features import Features, detect_sift, mutual_ratio_matches
from .pose import PoseEstimate
from .prepare import WorkingViews
from .refine import RefinedRender
from .render import RenderResult
from .utils.distance import known_ring
from .utils.resolution import config_px, resize_long
from .utils.rotations import skew


@dataclass(frozen=True)
class ScreenedRender:
    """The refined render with what may not be copied taken out: ``image`` HxWx3 uint8 (zero where
    ``alpha`` is False) and ``alpha`` at target resolution (the refined render's own arrays where
    nothing was refused); ``refused_object`` / ``refused_masked`` / ``refused_stranger`` (HxW bool or
    None): hole pixels the render covered but that show the removed object again / come from pixels
    the user masked / continue reference content the target does not show around the hole."""

    image: np.ndarray
    alpha: np.ndarray
    refused_object: np.ndarray | None = None
    refused_masked: np.ndarray | None = None
    refused_stranger: np.ndarray | None = None
    object_matches: int = 0  # epipolar-consistent SIFT matches of the hole's content in this reference
    located: bool = False  # the removed object was located in the reference by those matches
    hole_pixels: int = 0

    def fraction(self, refused: np.ndarray | None) -> float:
        """Share of the hole in ``refused``."""
        return 0.0 if refused is None else float(np.count_nonzero(refused)) / max(self.hole_pixels, 1)

    def summary(self) -> str:
        parts = []
        if self.refused_object is not None:
            how = (
                f"located by {self.object_matches} matches"
                if self.located
                else "not located in the reference"
            )
            share = 100 * self.fraction(self.refused_object)
            parts.append(f"refused {share:.1f}% of the hole showing the removed object ({how})")
        if self.refused_masked is not None:
            parts.append(f"{100 * self.fraction(self.refused_masked):.1f}% masked in the reference")
        if self.refused_stranger is not None:
            parts.append(
                f"{100 * self.fraction(self.refused_stranger):.1f}% not in the target around the hole"
            )
        return ", ".join(parts) or "nothing to refuse"

    def report(self) -> dict[str, Any]:
        return {
            "refused_object_fraction": self.fraction(self.refused_object),
            "refused_masked_fraction": self.fraction(self.refused_masked),
            "refused_stranger_fraction": self.fraction(self.refused_stranger),
            "object_matches": self.object_matches,
            "object_located": self.located,
        }


def shows_object(target: np.ndarray, hole: np.ndarray, min_texture: float) -> bool:
    """Whether the hole of ``target`` (as given, before blanking) shows something to remove: its grey
    values vary by more than ``min_texture`` (standard deviation, 0-255). A blanked or constant hole
    does not.

    >>> img = np.zeros((8, 8, 3), np.uint8); hole = np.ones((8, 8), bool)
    >>> shows_object(img, hole, 2.0), shows_object(np.arange(192, dtype=np.uint8).reshape(8, 8, 3), hole, 2.0)
    (False, True)
    """
    grey = cv2.cvtColor(np.ascontiguousarray(target), cv2.COLOR_RGB2GRAY)[hole]
    return grey.size > 0 and float(grey.std()) > min_texture


def screen_render(
    refined: RefinedRender,
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    shown: np.ndarray | None,
    exclude: np.ndarray | None,
    views: WorkingViews,
    matches: Matches,
    focal: FocalEstimate,
    pose: PoseEstimate,
    cfg: FillConfig,
    location: tuple[np.ndarray | None, int] | None = None,
    object_seen: np.ndarray | None = None,
) -> ScreenedRender:
    """Take out of ``refined`` what shows the removed object again, what comes from reference pixels
    the user masked and what continues a stranger. ``target``: the target with its hole blanked
    (HxWx3 uint8); ``shown``: the target as the user gave it when its hole shows something to
    remove, else None; ``exclude``: the reference's own mask (HxW bool at the source's input size,
    True = never copy) or None; ``source``: the reference at input size; ``location``:
    :func:`locate_object`'s result when the render stage already looked for the object, and
    ``object_seen`` where it left the object out of the mesh and the object would have shown (counted
    as refused where nothing else covers it)."""
    sc = cfg.screen
    n_hole = int(np.count_nonzero(hole))
    rows, cols = refined.render.window()
    field = refined.render
    covered = refined.alpha[rows, cols] & hole[rows, cols]
    refused_masked = refused_object = refused_stranger = None
    if exclude is not None:
        refused_masked = np.zeros(hole.shape, bool)
        refused_masked[rows, cols] = _sampled(exclude, field, rows, cols) & covered
    object_matches, located = 0, False
    if shown is not None:
        in_source, object_matches = location or locate_object(shown, source, views, matches, focal, pose, cfg)
        located = in_source is not None
        refused_object = np.zeros(hole.shape, bool)
        if located:
            refused_object[rows, cols] = _sampled(in_source, field, rows, cols) & covered
        if object_seen is not None:
            refused_object |= object_seen & ~refined.alpha
        if sc.appearance_threshold > 0:
            seen = seen_again(
                refined.image[rows, cols], shown[rows, cols], hole[rows, cols], covered, hole.shape, sc
            )
            refused_object[rows, cols] |= seen
    refused = np.zeros(hole.shape, bool)
    for r in (refused_masked, refused_object):
        if r is not None:
            refused |= r
    if sc.stranger_threshold > 0:
        refused_stranger = np.zeros(hole.shape, bool)
        # The source's own colours at the field: the refine stage's local colour gain is fitted on the
        # ring, so it would fade a stranger exactly where this test looks for it.
        refused_stranger[rows, cols] = strangers(
            field.sample_window(source),
            target[rows, cols],
            hole[rows, cols],
            refined.alpha[rows, cols] & ~refused[rows, cols],
            hole.shape,
            sc,
        )
        refused |= refused_stranger
    if not refused.any():
        return ScreenedRender(
            refined.image, refined.alpha, refused_object, refused_masked, refused_stranger,
            object_matches, located, n_hole,
        )  # fmt: skip
    alpha = refined.alpha & ~refused
    image = refined.image.copy()
    image[refused] = 0
    return ScreenedRender(
        image, alpha, refused_object, refused_masked, refused_stranger, object_matches, located, n_hole
    )


#: Long side (px) at which the stranger test runs: it finds regions tens of pixels wide, and at full
#: resolution its watershed and statistics cost a tenth of a 1280-px fill.
STRANGER_TEST_SIDE = 640


def strangers(
    render: np.ndarray,
    target: np.ndarray,
    hole: np.ndarray,
    alpha: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
) -> np.ndarray:
    """Hole pixels of a window (covered by ``alpha``) whose render continues content that the target
    does not show around the hole: regions of the render within ``sc.stranger_ring_px`` of the hole
    that disagree with ``target`` (after the median colour difference there is taken out; over
    ``sc.stranger_threshold``, and over ``sc.stranger_shift_threshold`` with the render shifted by
    up to 12 px; wide and large enough, near the hole) are grown into it by the watershed, against
    the pixels that agree with the target (under ``sc.stranger_agreement``). ``shape``: the full
    target's, for pixel scaling. Runs with the window's long side at most :data:`STRANGER_TEST_SIDE`.

    >>> hole = np.zeros((40, 60), bool); hole[10:30, 20:40] = True
    >>> target = np.full((40, 60, 3), 120, np.uint8); target[hole] = 0
    >>> render = np.full((40, 60, 3), 120, np.uint8); render[:, 34:] = 240  # a stranger
    >>> out = strangers(render, target, hole, np.ones((40, 60), bool), (720, 1280), ScreenConfig())
    >>> bool(out[:, 35:].sum() == hole[:, 35:].sum()), bool(out[:, :34].any())  # (the seam: unlabelled)
    (True, False)
    """
    h, w = hole.shape
    f = min(1.0, STRANGER_TEST_SIDE / max(h, w))
    px = config_px(1.0, shape) * f
    if f == 1.0:
        return _strangers(render, target, hole, alpha, px, sc)
    size = (max(round(w * f), 1), max(round(h * f), 1))

    def small(mask: np.ndarray) -> np.ndarray:
        return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0

    found = _strangers(
        cv2.resize(render, size, interpolation=cv2.INTER_AREA),
        cv2.resize(target, size, interpolation=cv2.INTER_AREA),
        small(hole),
        small(alpha),
        px,
        sc,
    )
    return (cv2.resize(found.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0) & alpha & hole


def _strangers(
    render: np.ndarray, target: np.ndarray, hole: np.ndarray, alpha: np.ndarray, px: float, sc: ScreenConfig
) -> np.ndarray:
    """:func:`strangers` at the resolution given, ``px`` pixels per config pixel."""
    ring = alpha & known_ring(hole, sc.stranger_ring_px * px)
    if not ring.any():
        return np.zeros(hole.shape, bool)
    k = _odd(5.0 * px)
    # The exposure and white balance of the two photos: the median difference around the hole.
    level = target.astype(np.float32) + np.median(render[ring].astype(np.float32) - target[ring], axis=0)
    raw = np.abs(render - level).mean(axis=2)
    diff = cv2.blur(raw, (k, k))
    # Both the box mean and the pixel itself: the mean alone spreads a stranger's edge outwards. A
    # render that is only misaligned (depth off at an occlusion edge) agrees once shifted a little;
    # a stranger does not.
    reach = 12.0 * px
    seeds = ring & (diff > sc.stranger_threshold) & (raw > sc.stranger_threshold)
    seeds &= _shifted_min_diff(render, level, k, reach) > sc.stranger_shift_threshold
    # An opening removes the thin lines that misalignment leaves along edges.
    m = max(3, _odd(sc.stranger_min_px / 2 * px))
    seeds = cv2.morphologyEx(seeds.astype(np.uint8), cv2.MORPH_OPEN, np.ones((m, m), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(seeds, connectivity=8)
    # Within the shift's reach of the hole: the band a shift explains lies between.
    near = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_odd(2 * reach + 3),) * 2)
    touching = cv2.dilate(hole.astype(np.uint8), near) > 0
    big = stats[:, cv2.CC_STAT_AREA] >= (sc.stranger_min_px * px) ** 2
    keep = np.zeros(n, bool)
    keep[np.unique(labels[touching & (labels > 0)])] = True
    keep &= big
    keep[0] = False
    seeded = keep[labels]
    agree = ring & (diff < sc.stranger_agreement)
    if not seeded.any() or not agree.any():
        return np.zeros(hole.shape, bool)
    # Watershed (not a colour threshold): the stranger's own edges stop its growth, whatever its colours.
    # Pixels the render does not cover are no marker: as one they flooded the stranger from every gap
    # in the render (cuts at depth edges) and stopped its growth there.
    markers = np.zeros(hole.shape, np.int32)
    markers[agree] = 2
    markers[seeded] = 1
    cv2.watershed(np.ascontiguousarray(render), markers)
    return (markers == 1) & alpha & hole


#: Long side (px) at which the test between references runs: it compares regions tens of pixels wide
#: in every pair of references.
CROSS_TEST_SIDE = 640


def cross_strangers(
    images: np.ndarray,
    alphas: np.ndarray,
    hole: np.ndarray,
    target: np.ndarray,
    evidence: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
    disputed: bool = False,
    trust: np.ndarray | None = None,
    ratio: float = 0.5,
) -> np.ndarray:
    """(K, H, W) bool: hole pixels of a window where a reference's render shows what the other
    references covering them do not (a stranger wholly inside the hole's footprint, which the
    target cannot expose). ``images`` (K, H, W, 3 float32): the renders, colour-corrected to the
    target; ``alphas``: where they cover; ``target``: the window, hole blanked; ``evidence``
    (K, H, W bool): where the stranger test of :func:`strangers` already refused; ``trust``
    (K, H, W, default all equal): how far each render is to be trusted at each pixel (the fuse
    stage's scores).

    Two renders disagree where their colours differ by more than ``sc.stranger_threshold`` (over a
    5-px box), and by more than ``sc.cross_shift_threshold`` with either one shifted by up to 12 px
    (misalignment is not disagreement).
    Where three or more cover a pixel, a render that disagrees with all the others there, while two
    of them agree with each other and are trusted at least ``ratio`` times as much, is the
    stranger. Where two cover it, the stranger is the render that continues a region the stranger
    test refused in it (``evidence`` within the shift's reach) while the other does not, again
    unless the other is trusted less than ``ratio`` times as much; otherwise the scores choose.
    With ``disputed``, a render that disagrees with every other one covering a pixel is refused
    there even when nothing says which is the stranger (then all are, and the pixel is painted).
    Found regions are grown over the stranger's render by OpenCV's watershed against its pixels
    that agree with another render or with the target around the hole, as :func:`strangers` grows
    its own. Runs with the long side at most :data:`CROSS_TEST_SIDE`.

    >>> hole = np.zeros((80, 120), bool); hole[10:70, 20:100] = True
    >>> images = np.full((3, 80, 120, 3), 100, np.float32); images[2, 20:60, 30:90] = 230
    >>> target = np.full((80, 120, 3), 100, np.uint8); target[hole] = 0
    >>> alphas = np.ones((3, 80, 120), bool); none = np.zeros((3, 80, 120), bool)
    >>> out = cross_strangers(images, alphas, hole, target, none, (720, 1280), ScreenConfig())
    >>> stranger = out[2, 20:60, 30:90]  # where the third render shows it
    >>> bool(out[:2].any()), round(float(stranger.mean()), 2), int(out[2].sum() - stranger.sum())
    (False, 1.0, 0)
    """
    n, h, w = alphas.shape
    out = np.zeros(alphas.shape, bool)
    if n < 2 or sc.stranger_threshold <= 0:
        return out
    f = min(1.0, CROSS_TEST_SIDE / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))

    def small(mask: np.ndarray) -> np.ndarray:
        return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0

    found = _cross_strangers(
        np.stack([cv2.resize(i, size, interpolation=cv2.INTER_AREA) for i in images]),
        np.stack([small(a) for a in alphas]),
        small(hole),
        cv2.resize(target, size, interpolation=cv2.INTER_AREA).astype(np.float32),
        np.stack([small(e) for e in evidence]),
        config_px(1.0, shape) * f,
        sc,
        disputed,
        np.ones(alphas.shape, np.float32)
        if trust is None
        else np.stack([cv2.resize(t.astype(np.float32), size, interpolation=cv2.INTER_AREA) for t in trust]),
        ratio,
    )
    for k in range(n):
        if found[k].any():
            up = cv2.resize(found[k].astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
            out[k] = up & alphas[k] & hole
    return out


def _cross_strangers(
    images: np.ndarray,
    alphas: np.ndarray,
    hole: np.ndarray,
    target: np.ndarray,
    evidence: np.ndarray,
    px: float,
    sc: ScreenConfig,
    disputed: bool,
    trust: np.ndarray,
    ratio: float,
) -> np.ndarray:
    """:func:`cross_strangers` at the resolution given, ``px`` pixels per config pixel."""
    n = len(images)
    k = _odd(5.0 * px)
    reach = 12.0 * px
    box = np.ones((k, k), np.uint8)
    # Box means next to a render's border mix in its zeros: compare only where both cover a full box.
    inner = np.stack([cv2.erode(a.astype(np.uint8), box) > 0 for a in alphas])
    disagree = np.zeros((n, n, *hole.shape), bool)
    agree = np.zeros(alphas.shape, bool)
    for i in range(n):
        for j in range(i + 1, n):
            both = inner[i] & inner[j]
            if not (both & hole).any():
                continue
            diff = cv2.blur(np.abs(images[i] - images[j]).mean(axis=2), (k, k))
            apart = both & (diff > sc.stranger_threshold)
            if apart.any():
                apart &= _shifted_min_diff(images[i], images[j], k, reach) > sc.cross_shift_threshold
                apart &= _shifted_min_diff(images[j], images[i], k, reach) > sc.cross_shift_threshold
            disagree[i, j] = disagree[j, i] = apart
            close = both & (diff < sc.stranger_agreement)
            agree[i] |= close
            agree[j] |= close
    if not disagree.any():
        return np.zeros(alphas.shape, bool)
    covering = inner.sum(axis=0)
    seeds = np.zeros(alphas.shape, bool)
    for i in range(n):
        others = [j for j in range(n) if j != i]
        against = disagree[i].sum(axis=0)
        # Two of the others that cover a pixel and agree there outvote this one.
        pair_agrees = np.zeros(hole.shape, bool)
        for a, b in ((a, b) for x, a in enumerate(others) for b in others[x + 1 :]):
            trusted = (trust[a] >= ratio * trust[i]) & (trust[b] >= ratio * trust[i])
            pair_agrees |= inner[a] & inner[b] & ~disagree[a, b] & trusted
        seeds[i] = hole & inner[i] & (covering >= 3) & (against == covering - 1) & pair_agrees
    two = hole & (covering == 2)
    if two.any():
        _two_way_seeds(inner, disagree, two, evidence, reach, seeds, trust, ratio)
    if disputed:
        decided = seeds.copy()
        for i in range(n):
            alone = hole & inner[i] & (covering >= 2) & (disagree[i].sum(axis=0) == covering - 1)
            # Where another render was found to be the stranger, this one is not in dispute.
            others = np.delete(decided, i, axis=0).any(axis=0)
            seeds[i] |= alone & ~others
    m = max(3, _odd(sc.stranger_min_px / 2 * px))
    min_area = (sc.stranger_min_px * px) ** 2
    ring = known_ring(hole, sc.stranger_ring_px * px)
    out = np.zeros(alphas.shape, bool)
    for i in range(n):
        if not seeds[i].any():
            continue
        opened = cv2.morphologyEx(seeds[i].astype(np.uint8), cv2.MORPH_OPEN, np.ones((m, m), np.uint8))
        _, labels, stats, _ = cv2.connectedComponentsWithStats(opened, connectivity=8)
        big = stats[:, cv2.CC_STAT_AREA] >= min_area
        big[0] = False
        seeded = big[labels]
        if not seeded.any():
            continue
        # The render's pixels that agree with another render, or with the target around the hole.
        fits = (agree[i] & ~seeded) | (
            ring
            & alphas[i]
            & (cv2.blur(np.abs(images[i] - target).mean(axis=2), (k, k)) < sc.stranger_agreement)
        )
        markers = np.zeros(hole.shape, np.int32)  # no marker where it does not cover, as in :func:`strangers`
        markers[fits] = 2
        markers[seeded] = 1
        cv2.watershed(np.ascontiguousarray(images[i].clip(0, 255).astype(np.uint8)), markers)
        grown = markers == 1
        # The watershed leaves its seam (-1) unlabelled: the seam around the stranger is refused too.
        grown |= (markers == -1) & (cv2.dilate(grown.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
        out[i] = grown & alphas[i] & hole
    return out


def _two_way_seeds(
    inner: np.ndarray,
    disagree: np.ndarray,
    two: np.ndarray,
    evidence: np.ndarray,
    reach: float,
    seeds: np.ndarray,
    trust: np.ndarray,
    ratio: float,
) -> None:
    """Into ``seeds``: of each region where exactly two renders cover the hole and disagree, the
    render that continues a region the stranger test refused in it (``evidence`` within ``reach``)
    while the other does not, unless the other scores below ``ratio`` of it there."""
    near = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (_odd(2 * reach + 3),) * 2)
    refused_near = np.stack([cv2.dilate(e.astype(np.uint8), near) > 0 for e in evidence])
    n = len(inner)
    for i in range(n):
        for j in range(i + 1, n):
            region = two & inner[i] & inner[j] & disagree[i, j]
            if not region.any():
                continue
            count, labels = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
            for c in range(1, count):
                part = labels == c
                ev_i, ev_j = (refused_near[i] & part).any(), (refused_near[j] & part).any()
                if ev_i == ev_j:
                    continue  # nothing tells which one is the stranger: the scores choose
                s, o = (i, j) if ev_i else (j, i)
                if float(trust[o][part].mean()) >= ratio * float(trust[s][part].mean()):
                    seeds[s] |= part


def object_in_render(mask: np.ndarray, field: RenderResult, hole: np.ndarray) -> np.ndarray:
    """HxW bool: the hole pixels where the render ``field`` shows the source pixels of ``mask``."""
    out = np.zeros(hole.shape, bool)
    rows, cols = field.window()
    out[rows, cols] = _sampled(mask, field, rows, cols) & field.alpha[rows, cols] & hole[rows, cols]
    return out


def _sampled(mask: np.ndarray, field: RenderResult, rows: slice, cols: slice) -> np.ndarray:
    """``mask`` (source pixels, input size) read at the correspondence field's window (nearest)."""
    return (
        cv2.remap(
            mask.astype(np.uint8), field.map_x[rows, cols], field.map_y[rows, cols], cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0,
        )
        > 0
    )  # fmt: skip


def locate_object(
    shown: np.ndarray,
    source: np.ndarray,
    views: WorkingViews,
    matches: Matches,
    focal: FocalEstimate,
    pose: PoseEstimate,
    cfg: FillConfig,
) -> tuple[np.ndarray | None, int]:
    """(HxW bool at the source's input size where the reference shows the removed object, or None
    when it cannot be located; the number of epipolar-consistent matches of the hole's content)."""
    sc, mc = cfg.screen, cfg.matching
    shown_w = resize_long(shown, cfg.working_max_side)
    hole_w = views.hole
    feats_s = matches.source_features
    if feats_s is None:
        return None, 0
    # SIFT on the hole's window only (the whole image would cost as much as the match stage).
    rows, cols = mask_window(hole_w, 16)
    grey_t = cv2.cvtColor(np.ascontiguousarray(shown_w[rows, cols]), cv2.COLOR_RGB2GRAY)
    detect = cv2.dilate(hole_w[rows, cols].astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
    feats_t = detect_sift(grey_t, mc.max_features, detect)
    if len(feats_t) < sc.min_object_matches:
        return None, 0
    feats_t = Features(feats_t.pts + [cols.start, rows.start], feats_t.desc)
    pairs = mutual_ratio_matches(feats_t.desc, feats_s.desc, mc.ratio, True)
    pts_t, pts_s = feats_t.pts[pairs[:, 0]], feats_s.pts[pairs[:, 1]]
    if pose.status == "ok":
        F = _fundamental(pose.T, focal.K_target.K, focal.K_source.K)
        keep = _sampson_px(F, pts_t, pts_s) < sc.object_epipolar_px * views.px_scale
        pts_t, pts_s = pts_t[keep], pts_s[keep]
    n = len(pts_t)
    if n < sc.min_object_matches:
        return None, n
    H, inliers = cv2.findHomography(pts_t, pts_s, cv2.USAC_MAGSAC, 3.0 * views.ransac_px)
    if H is None or int(inliers.sum()) < sc.min_object_matches // 2:
        return None, n
    hs, ws = views.source.shape[:2]
    # The hole's content seen from the reference through the homography, and where it lands.
    warped = cv2.warpPerspective(shown_w, H, (ws, hs), flags=cv2.INTER_LINEAR)
    landed = cv2.warpPerspective(hole_w.astype(np.uint8), H, (ws, hs), flags=cv2.INTER_NEAREST) > 0
    source_w = resize_long(source, cfg.working_max_side)
    k = _odd(config_px(sc.appearance_patch_px, views.source.shape))
    diff = cv2.blur(np.abs(warped.astype(np.float32) - source_w.astype(np.float32)).mean(axis=2), (k, k))
    agree = landed & (diff < 2.0 * max(sc.appearance_threshold, 1.0))
    r = _odd(2.0 * config_px(sc.object_margin_px, views.source.shape))
    obj = cv2.dilate(agree.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (r, r))) > 0
    full = cv2.resize(
        obj.astype(np.uint8), (source.shape[1], source.shape[0]), interpolation=cv2.INTER_NEAREST
    )
    return full > 0, n


def seen_again(
    render: np.ndarray,
    shown: np.ndarray,
    hole: np.ndarray,
    covered: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
) -> np.ndarray:
    """Covered hole pixels (of a window) where the render's patch equals the hole's own content: in
    regions that reach more than a patch's width into the hole, on textured content only."""
    k = _odd(config_px(sc.appearance_patch_px, shape))
    diff = cv2.blur(np.abs(render.astype(np.float32) - shown.astype(np.float32)).mean(axis=2), (k, k))
    grey = cv2.cvtColor(np.ascontiguousarray(shown), cv2.COLOR_RGB2GRAY).astype(np.float32)
    mean = cv2.blur(grey, (k, k))
    std = np.sqrt(np.maximum(cv2.blur(grey * grey, (k, k)) - mean * mean, 0.0))
    candidate = covered & (diff < sc.appearance_threshold) & (std > sc.appearance_min_texture)
    if not candidate.any():
        return candidate
    inner = cv2.distanceTransform(hole.astype(np.uint8), cv2.DIST_L2, 3) > k
    n, labels = cv2.connectedComponents(candidate.astype(np.uint8), connectivity=8)
    deep = np.zeros(n, bool)
    deep[np.unique(labels[candidate & inner])] = True
    deep[0] = False
    return deep[labels]


def _shifted_min_diff(render: np.ndarray, target: np.ndarray, k: int, reach_px: float) -> np.ndarray:
    """Per pixel, the smallest box mean (side ``k``) of the absolute difference between ``target``
    (float32) and ``render`` shifted by up to ``reach_px`` in each direction (7 x 7 shifts at most).
    Computed with the long side at most 256 px: telling misalignment from other content needs no
    fine detail, and 49 passes at 640 px would cost more than the rest of the screen stage."""
    h, w = render.shape[:2]
    f = min(1.0, 256 / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))
    r_img = cv2.resize(render, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    t_img = cv2.resize(target, size, interpolation=cv2.INTER_AREA)
    ks = _odd(k * f)
    r = max(1, round(reach_px * f))
    step = max(1, round(r / 3))
    padded = cv2.copyMakeBorder(r_img, r, r, r, r, cv2.BORDER_REPLICATE)
    best = np.full(r_img.shape[:2], np.inf, np.float32)
    for dy in range(-r, r + 1, step):
        for dx in range(-r, r + 1, step):
            shifted = padded[r + dy : r + dy + size[1], r + dx : r + dx + size[0]]
            d = np.abs(shifted - t_img)
            # = d.mean(axis=2) to the bit (float32, summed in the same order), 3x faster
            np.minimum(best, cv2.blur((d[..., 0] + d[..., 1] + d[..., 2]) / 3, (ks, ks)), out=best)
    return cv2.resize(best, (w, h), interpolation=cv2.INTER_LINEAR)


def _odd(px: float) -> int:
    return max(1, round(px) // 2 * 2 + 1)


def _fundamental(T: np.ndarray, K_t: np.ndarray, K_s: np.ndarray) -> np.ndarray:
    """F with x_t^T F x_s = 0 for the pose ``T`` (source -> target)."""
    return np.linalg.inv(K_t).T @ skew(T[:3, 3]) @ T[:3, :3] @ np.linalg.inv(K_s)


def _sampson_px(F: np.ndarray, pts_t: np.ndarray, pts_s: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of each correspondence to the epipolar geometry ``F``."""
    xs = np.column_stack([pts_s, np.ones(len(pts_s))])
    xt = np.column_stack([pts_t, np.ones(len(pts_t))])
    Fx = xs @ F.T
    Ftx = xt @ F
    num = np.einsum("ij,ij->i", xt, Fx) ** 2
    den = Fx[:, 0] ** 2 + Fx[:, 1] ** 2 + Ftx[:, 0] ** 2 + Ftx[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-12))
