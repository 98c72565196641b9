"""The fill as a flat sequence of typed stages.

Per reference photo (:func:`run_reference`)::

    prepare -> match -> focal -> pose -> triangulate -> depth -> optimize -> render -> refine -> screen

with several references, every one stops after ``optimize`` for the multi-view depth stage
(:mod:`geofill.multiview`: each one's depth behind the hole measured from the others) and then goes
on; then, once for the fill (:func:`fill`): fuse the references' renders -> composite with
single-image inpainting. Each stage is a function from typed inputs to a frozen result that owns its
``summary()`` line (printed with the stage's time) and its ``report()`` section. A reference that
cannot help raises :class:`geofill.errors.ReferenceUnusable` in whichever stage finds out; it is
dropped with that reason and the others go on. Any other exception is a bug and propagates.

:func:`run_reference` stops after any stage (``until=``) and resumes from the artifacts of an
earlier run (``resume=``): benchmarks and the evaluation use that instead of patching internals.
Geometry runs at a working resolution (long side <= ``working_max_side``); rendering and compositing
run at the input resolution.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from .camera import Intrinsics
from .composite.inpaint import Inpainter, get_inpainter
from .composite.merge import merge_fill
from .composite.planes import SceneDepth
from .config import FillConfig, OptimizeConfig
from .depth import BackendChoice, DepthContext, choose_backend
from .depth.stage import SourceDepth, estimate_depth, rotation_only_depth
from .errors import ArrayFormatError, ReferenceUnusable
from .extras import install_hint
from .focal import FocalEstimate, estimate_focal, shared_estimate, shared_focal_scale
from .fuse import Fusion, fuse_references
from .fuse.lineup import misaligned, ring_correlation
from .intrinsics import ExifLens
from .io import LoadedImage, as_rgb_uint8, as_source_mask, validate_pair
from .joint import JointDatabase, agreeing, joint_focal, joint_pose, prior_conflict
from .joint import available as joint_available
from .joint import extract as extract_joint
from .joint import register as register_joint
from .match import Matches, match_pair
from .match.features import Features
from .multiview import MultiViewDepth, ViewGeometry, multiview_depth
from .optimize.stage import Geometry, optimize_geometry
from .pose import PoseEstimate, estimate_pose
from .preflight import check_resources
from .prepare import WorkingViews, prepare_views
from .progress import Progress
from .refine import RefinedRender, refine_render
from .render import ReferenceRender, render_reference
from .screen import (
    DepthLocation,
    ScreenedRender,
    locate_by_appearance,
    locate_by_depth,
    locate_on_surface,
    locate_together,
    object_in_render,
    screen_render,
    shows_object,
)
from .triangulate import TriangulatedPoints, triangulate
from .utils.jit import warm_up
from .utils.resolution import config_px

#: The per-reference stages in order, as (stage name, artifact field).
REFERENCE_STAGES: tuple[tuple[str, str], ...] = (
    ("prepare", "views"),
    ("match", "matches"),
    ("focal", "focal"),
    ("pose", "pose"),
    ("triangulate", "points"),
    ("depth", "depth"),
    ("optimize", "geometry"),
    ("render", "render"),
    ("refine", "refined"),
    ("screen", "screened"),
)

#: Why a reference dropped at a stage could not help, in the words a photographer understands (the
#: technical reason stays in the report).
DROPPED_WORDS: dict[str, str] = {
    "prepare": "it could not be prepared for matching",
    "match": "it does not show enough of the same scene",
    "focal": "it does not show enough of the same scene",
    "pose": "it does not show enough of the same scene",
    "triangulate": "the scene's depth could not be measured from it",
    "depth": "the scene's depth could not be measured from it",
    "optimize": "the scene's depth could not be measured from it",
    "render": "it does not see what is behind the hole",
    "refine": "it does not see what is behind the hole",
    "screen": "it does not see what is behind the hole",
    "line-up": "its view does not line up with the photo around the hole",
}


@dataclass(frozen=True)
class FillContext:
    """What every reference shares: the target (hole blanked), its hole, the resolved depth backend
    and the configuration. Built once per fill by :func:`prepare_fill`."""

    target: np.ndarray  # HxWx3 uint8, hole pixels zeroed
    hole: np.ndarray  # HxW bool
    #: The target as given when its hole shows something to remove (the object: a negative, never
    #: content), else None.
    shown: np.ndarray | None
    target_exif: ExifLens | None
    depth_choice: BackendChoice
    inpainter: Inpainter
    cfg: FillConfig
    n_references: int = 1


@dataclass(frozen=True)
class ReferenceArtifacts:
    """One reference's stage results so far (None where not reached) and, if it was dropped, why."""

    index: int  # 1-based, in the order the references were given
    source: np.ndarray  # HxWx3 uint8 as given
    exif: ExifLens | None = None
    exclude: np.ndarray | None = None  # HxW bool at the source's size: pixels never to copy
    name: str = ""  # what the user calls it (its file name), for the plain messages
    views: WorkingViews | None = None
    matches: Matches | None = None
    focal: FocalEstimate | None = None
    pose: PoseEstimate | None = None
    points: TriangulatedPoints | None = None
    depth: SourceDepth | None = None
    geometry: Geometry | None = None
    render: ReferenceRender | None = None
    refined: RefinedRender | None = None
    screened: ScreenedRender | None = None
    # Its translation length in the joint registration's units (None: registered by its pair alone).
    joint_baseline: float | None = None
    dropped: str = ""  # the reason this reference cannot help ("" while it can)
    dropped_at: str = ""  # the stage that found it out
    timings_s: dict[str, float] = field(default_factory=dict)

    @property
    def dropped_words(self) -> str:
        """Why this reference was dropped, in plain words ("" when it was not)."""
        return DROPPED_WORDS.get(self.dropped_at, self.dropped) if self.dropped else ""

    @property
    def usable(self) -> bool:
        """Reached the screen stage without being dropped."""
        return self.screened is not None and not self.dropped

    def report(self) -> dict[str, Any]:
        """This reference's report: every stage reached, by stage name, plus the intrinsics used."""
        out: dict[str, Any] = {"index": self.index, "status": "dropped" if self.dropped else "used"}
        if self.name:
            out["name"] = self.name
        out["reason"] = self.dropped
        if self.dropped:
            out["reason_words"] = self.dropped_words
            out["dropped_at"] = self.dropped_at
        K = self.intrinsics()
        if K is not None:
            h_t, w_t = self.views.target_shape
            h_s, w_s = self.source.shape[:2]
            out["intrinsics_target"] = K[0].resized(w_t, h_t).to_json()
            out["intrinsics_source"] = K[1].resized(w_s, h_s).to_json()
        for stage, name in REFERENCE_STAGES:
            result = getattr(self, name)
            if result is not None:
                out[stage] = result.report()
        out["timings_s"] = dict(self.timings_s)
        return out

    def intrinsics(self) -> tuple[Intrinsics, Intrinsics] | None:
        """(target, source) intrinsics at working resolution as the latest stage left them."""
        for holder in (self.geometry, self.focal, self.views):
            if holder is not None:
                return holder.K_target, holder.K_source
        return None


@dataclass
class FillReport:
    """What happened, for humans and for ``--debug-dir``'s report.json. Units: px, degrees, seconds.

    ``status``: ``reference`` (at least one reference supplied pixels) or ``single_image`` (every
    reference was dropped: the hole is painted by single-image inpainting; ``fallbacks`` says why)."""

    status: str = "reference"
    fallbacks: list[str] = field(default_factory=list)
    hole_pixels: int = 0
    references: list[dict[str, Any]] = field(default_factory=list)
    supplied_fraction: list[float] = field(default_factory=list)  # per reference, of the hole
    painted_fraction: float = 1.0  # of the hole, by single-image inpainting
    #: Of the hole, the painted part by why it was not copied (disjoint; they add up to
    #: ``painted_fraction``): ``masked`` (a reference covered it from pixels the user masked),
    #: ``removed_object`` (it showed the removed object), ``stranger`` (it continued something the
    #: target does not show around the hole, or the other references covering those pixels
    #: contradicted it), ``mismatch`` (it did not line up with the ring), ``unseen`` (no reference's
    #: render covers it).
    refused_fraction: dict[str, float] = field(default_factory=dict)
    #: Per reference, of the hole: what it supplied where its render disagrees with every other
    #: reference's render covering those pixels (the fuse stage's :attr:`Fusion.disputed`).
    disputed_fraction: list[float] = field(default_factory=list)
    fusion: dict[str, Any] = field(default_factory=dict)
    #: With several references: per reference, its scale in the common frame and how much of its
    #: hole footprint got measured (not completed) depth (:mod:`geofill.multiview`).
    multiview: dict[str, Any] = field(default_factory=dict)
    #: With several references: how their cameras were registered (jointly, or per pair and why).
    registration: str = ""
    inpaint_method: str = ""
    depth_choice: str = ""
    #: Seconds per stage, summed over the references (which may run at the same time).
    timings_s: dict[str, float] = field(default_factory=dict)
    wall_s: float = 0.0  # the fill's elapsed time

    def dropped_words(self) -> list[str]:
        """Each reference that could not help, with why, in plain words.

        >>> FillReport(references=[{"index": 2, "status": "dropped", "reason_words": "it is blurred"}]).dropped_words()
        ['reference 2 was not used: it is blurred']
        """
        return [
            f"{_label(r['index'], r.get('name', ''))} was not used: {r['reason_words']}"
            for r in self.references
            if r.get("status") == "dropped"
        ]

    def filled_words(self, names: Sequence[str] | None = None) -> str:
        """Where the hole's pixels came from, in plain words; ``names`` name the references (their
        files) instead of their numbers.

        >>> FillReport(supplied_fraction=[0.25, 0.0], painted_fraction=0.75).filled_words(["a.jpg", "b.jpg"])
        '25% of the hole from a.jpg, 75% painted from its surroundings'
        """
        label = (lambda i: names[i - 1]) if names else (lambda i: f"reference {i}")
        # Rounded together, so that the shares printed add up to 100 % of the hole.
        shares = rounded_percent([*self.supplied_fraction, self.painted_fraction])
        parts = [f"{p}% from {label(i)}" for i, p in enumerate(shares[:-1], 1) if p > 0]
        if shares[-1] > 0 or not parts:
            parts.append(f"{shares[-1]}% painted from its surroundings")
        return f"{parts[0].replace('% ', '% of the hole ', 1)}" + "".join(f", {p}" for p in parts[1:])

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def refused_words(self, names: Sequence[str] | None = None) -> str:
        """Why what was painted was not copied, and where what was copied disagrees with the other
        references, in plain words ('' when neither). The reasons are disjoint shares of the painted
        part and, with ``unseen``, add up to it (rounded so that the printed figures do too).

        >>> FillReport(painted_fraction=0.5, refused_fraction={"removed_object": 0.4, "unseen": 0.1}).refused_words()
        '40% of the hole was not copied because the references showed the removed object, 10% no reference sees'
        """
        why = {
            "removed_object": "the references showed the removed object",
            "masked": "it was masked in the references",
            "stranger": "the references showed something there that your photo does not show around it",
            "mismatch": "the references did not line up with your photo around it there",
        }
        keys = [k for k in (*why, "unseen") if k in self.refused_fraction]
        painted = rounded_percent([*self.supplied_fraction, self.painted_fraction])[-1]
        shares = rounded_percent([self.refused_fraction[k] for k in keys], painted)
        parts = [
            f"{p}% no reference sees"
            if k == "unseen"
            else f"{p}% of the hole was not copied because {why[k]}"
            for k, p in zip(keys, shares, strict=True)
            if p > 0
        ]
        if parts and parts[0].endswith("no reference sees"):
            parts[0] = parts[0].replace("% no", "% of the hole no", 1)
        label = (lambda i: names[i - 1]) if names else (lambda i: f"reference {i}")
        warnings = [
            f"{100 * f:.0f}% of the hole copied from {label(i)} disagrees with the other references: check it"
            for i, f in enumerate(self.disputed_fraction, 1)
            if f >= 0.005
        ]
        return "; ".join([", ".join(parts)] * bool(parts) + warnings)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


@dataclass(frozen=True)
class FillResult:
    image: np.ndarray  # HxWx3 uint8; pixels outside the hole are the target's, byte for byte
    report: FillReport
    references: list[ReferenceArtifacts]
    fusion: Fusion | None
    #: HxW int16 at target size: -1 outside the hole, 0 painted by single-image inpainting,
    #: k >= 1 supplied by reference k (1-based, in the order given).
    source_map: np.ndarray


def rounded_percent(fractions: Sequence[float], total: int | None = None) -> list[int]:
    """``fractions`` (of the hole) as whole percentages that add up to ``total`` (default: their
    sum's, rounded); the largest remainders get the leftover points, so that the shares a line
    prints add up.

    >>> rounded_percent([1 / 3, 1 / 3, 1 / 3]), rounded_percent([0.004, 0.004], 1)
    ([34, 33, 33], [1, 0])
    """
    raw = [100 * f for f in fractions]
    out = [int(np.floor(r)) for r in raw]
    left = (round(sum(raw)) if total is None else total) - sum(out)
    for i in sorted(range(len(raw)), key=lambda i: out[i] - raw[i])[: max(left, 0)]:
        out[i] += 1
    return out


def prepare_fill(
    target: np.ndarray,
    mask: np.ndarray,
    sources: Sequence[np.ndarray],
    cfg: FillConfig,
    target_exif: ExifLens | None = None,
    say: Callable[[str], None] | None = None,
    detail: Callable[[str], None] | None = None,
) -> FillContext:
    """Check the inputs, blank the hole, and resolve the depth backend and the inpainter once;
    ``say`` is told of model downloads, ``detail`` which depth backend was chosen and why."""
    target = as_rgb_uint8(target)
    # The depth file and the depth model belong to the (first) reference the depth stage runs on.
    check_resources(cfg, (sources[0].shape[1], sources[0].shape[0]))
    hole = None
    for s in sources:
        hole = validate_pair(
            target,
            mask,
            as_rgb_uint8(s),
            min_side=cfg.min_side_px,
            max_pixels=cfg.max_pixels,
            max_mask_fraction=cfg.max_mask_fraction,
        )
    # Whatever the hole shows (the object being removed) is never content: every stage before the
    # screen sees it blanked, so the geometry depends on the known pixels only. Black beat a Telea
    # pre-fill (mean hole PSNR 19.02 vs 18.75 dB on the DEV pairs): keypoints are dropped near the
    # hole anyway, and a flat region gives the stereo and the flow no false texture. The screen
    # uses what it shows as a negative: reference content that shows it again is refused.
    refuse = cfg.screen.removed_object == "refuse"
    shown = target if refuse and shows_object(target, hole, cfg.screen.min_hole_texture) else None
    target = target.copy()
    target[hole] = 0
    choice = choose_backend(cfg.depth, say)
    if detail is not None:
        detail(f"depth backend: {choice.reason}")
    return FillContext(
        target, hole, shown, target_exif, choice, get_inpainter(cfg.inpaint, say), cfg, len(sources)
    )


def render_step(ctx: FillContext, a: ReferenceArtifacts) -> ReferenceRender:
    """The render stage. Where the hole shows an object to remove, it is located in the reference
    by depth (:func:`geofill.screen.depth.locate_by_depth`, on the first render's depth around the
    hole) and, with ``screen.cut_object`` (and several references, for "several"), the reference is
    rendered again without it, so that background it sees behind the object reaches the hole; the
    first render decides whether the reference sees the hole at all and where it would have shown
    the object. With several references the location and the cut wait for all of them
    (:func:`object_step`). The screen stage reuses the location."""
    cfg = ctx.cfg
    rendered = render_reference(a.geometry, a.source, ctx.hole, cfg.render, render_margin_px(cfg))
    if ctx.shown is None:
        return rendered
    g = a.geometry
    located = locate_by_depth(
        ctx.shown, ctx.hole, a.source, rendered.render, g.K_target, g.K_source, g.T, cfg.screen
    )
    if ctx.n_references > 1:
        return replace(rendered, located=located)
    located = _or_by_appearance(ctx, a, located)
    if cfg.screen.cut_object != "always":
        return replace(rendered, located=located)
    return _without_object(ctx, a, rendered, located)


def object_step(ctx: FillContext, refs: list[ReferenceArtifacts]) -> list[ReferenceArtifacts]:
    """With several references, after their render stage: the object located in each from the
    evidence of all (:func:`geofill.screen.depth.locate_together`) and, with ``screen.cut_object``,
    each rendered again without it."""
    ran = [r for r in refs if r.render is not None and r.render.located is not None]
    located = locate_together(
        [r.render.located for r in ran], ctx.hole, [r.source for r in ran], ctx.cfg.screen
    )
    out = {r.index: r for r in refs}
    for r, loc in zip(ran, located, strict=True):
        out[r.index] = replace(r, render=_without_object(ctx, r, r.render, _or_by_appearance(ctx, r, loc)))
    return [out[r.index] for r in refs]


def _or_by_appearance(ctx: FillContext, a: ReferenceArtifacts, located: DepthLocation) -> DepthLocation:
    """``located``, or where the depth test located nothing, what the reference shows on the ring's
    surface of the hole's content that the ring does not explain (an object flat on the surface:
    :func:`geofill.screen.surface.locate_on_surface`), or where that finds nothing either, the
    hole's content located in the reference by its look
    (:func:`geofill.screen.appearance.locate_by_appearance`). Not after the depth test located
    something: the ring leaves parts of the brushed margin unexplained too (in the ray-cast room,
    15 % of it), and beside a located object they would be refused for nothing."""
    if located.located or ctx.shown is None:
        return located
    flat = locate_on_surface(located, a.source, ctx.hole, ctx.cfg.screen)
    if flat is not None:
        return replace(located, source=flat, on_surface=True)
    found = locate_by_appearance(ctx.shown, a.source, a.views, a.matches, a.focal, a.pose, ctx.cfg)
    return located if found is None else replace(located, source=found, by_appearance=True)


def _without_object(
    ctx: FillContext, a: ReferenceArtifacts, rendered: ReferenceRender, located: DepthLocation
) -> ReferenceRender:
    """``rendered`` with ``located``, rendered again without the object where it is located and
    ``screen.cut_object`` is not off."""
    if not located.located or ctx.cfg.screen.cut_object == "off":
        return replace(rendered, located=located)
    margin = render_margin_px(ctx.cfg)
    opened = render_reference(
        a.geometry, a.source, ctx.hole, ctx.cfg.render, margin, located.source, check=False
    )
    return replace(
        opened, located=located, object_seen=object_in_render(located.source, rendered.render, ctx.hole)
    )


def run_reference(
    ctx: FillContext,
    ref: ReferenceArtifacts,
    progress: Progress | None = None,
    *,
    until: str | None = None,
) -> ReferenceArtifacts:
    """Run the per-reference stages on ``ref`` (resuming after the last one it holds) up to and
    including ``until`` (a :data:`REFERENCE_STAGES` name; all by default). A reference that cannot
    help comes back with ``dropped`` set to the reason; later stages are not run."""
    names = [s for s, _ in REFERENCE_STAGES]
    if until is not None and until not in names:
        raise ValueError(f"unknown stage {until!r}; stages: {names}")
    prog = progress or Progress(quiet=True)
    cfg, a = ctx.cfg, ref
    steps: dict[str, Callable[[ReferenceArtifacts], Any]] = {
        "prepare": lambda a: prepare_views(ctx.target, ctx.hole, a.source, cfg, ctx.target_exif, a.exif),
        "match": lambda a: related(match_pair(a.views.target_gray, a.views.source_gray, a.views.hole, cfg.matching, a.views.px_scale, (a.views.K_target.K, a.views.K_source.K))),
        "focal": lambda a: estimate_focal(a.matches, a.views.K_target, a.views.K_source, cfg.intrinsics, a.views.ransac_px),
        "pose": lambda a: usable_pose(estimate_pose(a.matches, a.focal.K_target, a.focal.K_source, cfg.geometry, cfg.matching, a.views.px_scale)),
        "triangulate": lambda a: triangulate_inliers(a.matches, a.pose, a.focal, cfg),
        "depth": lambda a: source_depth(a.views, a.focal, a.pose, a.points, ctx.depth_choice, a.source.shape, cfg),
        "optimize": lambda a: optimize_geometry(a.views, a.focal, a.pose, a.depth, a.matches, optimize_config(a, cfg)),
        "render": lambda a: render_step(ctx, a),
        "refine": lambda a: refine_render(ctx.target, ctx.hole, a.source, a.render.render, cfg.refine),
        "screen": lambda a: screen_render(a.refined, ctx.target, ctx.hole, a.source, ctx.shown, a.exclude, cfg, a.render.located, a.render.object_seen),
    }  # fmt: skip
    for i, (stage, name) in enumerate(REFERENCE_STAGES):
        if a.dropped:
            break
        if getattr(a, name) is None:
            try:
                with prog.stage(stage) as notes:
                    result = steps[stage](a)
                    notes.append(result.summary())
            except ReferenceUnusable as exc:
                a = replace(a, dropped=str(exc), dropped_at=stage)
                prog.detail(f"reference {a.index} cannot help: {exc}")
                prog.say(f"{_label(a.index, a.name)} was not used: {a.dropped_words}")
                prog.advance(len(REFERENCE_STAGES) - i)  # this stage and the ones it will not run
            else:
                a = replace(a, **{name: result})
        if stage == until:
            break
    return replace(a, timings_s={**ref.timings_s, **prog.timings})


def optimize_config(ref: ReferenceArtifacts, cfg: FillConfig) -> OptimizeConfig:
    """The optimize stage's settings for ``ref``: off for a jointly registered reference when
    ``registration.optimize_joint`` says so."""
    joint = ref.focal is not None and ref.focal.method == "joint"
    if joint and not cfg.registration.optimize_joint:
        return replace(cfg.optimize, enabled=False)
    return cfg.optimize


def _label(index: int, name: str) -> str:
    """How the plain messages name a reference: "reference 2", or "reference 2 (left.jpg)"."""
    return f"reference {index} ({name})" if name else f"reference {index}"


def related(matches: Matches) -> Matches:
    """``matches`` unless the ladder found that the reference shows another scene (then it cannot
    help, and the costly stages are not run)."""
    if matches.unrelated:
        raise ReferenceUnusable(matches.unrelated)
    return matches


def usable_pose(pose: PoseEstimate) -> PoseEstimate:
    """``pose`` unless it failed (then the reference cannot help)."""
    if not pose.usable:
        raise ReferenceUnusable(pose.reason)
    return pose


def triangulate_inliers(
    matches: Matches, pose: PoseEstimate, focal: FocalEstimate, cfg: FillConfig
) -> TriangulatedPoints:
    """The pose inliers triangulated (none for a pure rotation, which needs no depth)."""
    inl = pose.inliers if pose.status == "ok" else np.zeros(len(matches), bool)
    return triangulate(
        matches.pts_source[inl], matches.pts_target[inl], focal.K_source, focal.K_target, pose.T, cfg.geometry
    )


def source_depth(
    views: WorkingViews,
    focal: FocalEstimate,
    pose: PoseEstimate,
    points: TriangulatedPoints,
    choice: BackendChoice,
    source_shape: tuple[int, ...],
    cfg: FillConfig,
) -> SourceDepth:
    """The depth stage on one reference (constant depth for a pure rotation)."""
    if pose.status == "rotation_only":
        return rotation_only_depth(views.source.shape[:2])
    ctx = DepthContext(
        views.source,
        views.target,
        views.hole,
        focal.K_source,
        focal.K_target,
        pose,
        points,
        (source_shape[1], source_shape[0]),
        cfg.depth,
    )
    return estimate_depth(ctx, choice, cfg.geometry)


def render_margin_px(cfg: FillConfig) -> float:
    """Margin (px at the 1280-px reference) rendered around the hole's bounding box: the known ring
    refinement measures on (``refine.band_px``) and half as much again for the flow to move it."""
    return 1.5 * cfg.refine.band_px


def fill(
    target: np.ndarray,
    mask: np.ndarray,
    sources: np.ndarray | Sequence[np.ndarray],
    config: FillConfig | None = None,
    *,
    target_exif: ExifLens | None = None,
    source_exifs: Sequence[ExifLens | None] | None = None,
    source_masks: Sequence[np.ndarray | None] | None = None,
    source_names: Sequence[str] | None = None,
    progress: Progress | None = None,
) -> FillResult:
    """Fill the hole ``mask`` (True/255 = hole) of ``target`` with content from ``sources``.

    What the hole shows is what the user removes: reference content that shows it again is not
    copied (``screen.removed_object``). ``source_masks`` (one per source, None for none; True/255 =
    masked) mark what must never be copied from each reference; ``source_names`` (their file names,
    say) name them in the plain messages.

    ``sources`` is one image or a sequence of them (other photos of the scene), each with its own
    entry in ``source_exifs``. Images are HxWx3 uint8 RGB (other dtypes/channels are normalised);
    sizes may differ. Raises :class:`geofill.errors.InputError` subclasses for bad inputs. A
    reference that cannot help is dropped with its reason (``result.report.references``); when
    none helps, the hole is painted by single-image inpainting (``status == "single_image"``).

    >>> from geofill.synthetic import make_pair
    >>> pair = make_pair(seed=0, width=320, height=240)
    >>> result = fill(pair.target, pair.hole, [pair.source])
    >>> result.report.status, bool((result.image[~pair.hole] == pair.target[~pair.hole]).all())
    ('reference', True)
    """
    warm_up()  # numba starts while matching runs
    cfg = config or FillConfig()
    prog = progress or Progress(quiet=True, time_budget_s=cfg.time_budget_s)
    images = [sources] if isinstance(sources, np.ndarray) and sources.ndim == 3 else list(sources)
    if not images:
        raise ArrayFormatError("no reference image given: pass at least one source")
    exifs = list(source_exifs) if source_exifs is not None else [None] * len(images)
    if len(exifs) != len(images):
        raise ArrayFormatError(f"{len(exifs)} source EXIF entries for {len(images)} sources")
    masks = list(source_masks) if source_masks is not None else [None] * len(images)
    if len(masks) != len(images):
        raise ArrayFormatError(f"{len(masks)} source masks for {len(images)} sources")
    started = prog.wall_s()
    many = len(images) > 1  # at most one of each step across references ("shared focal", ...)
    steps = many * (
        1
        + (cfg.registration.joint == "auto")
        + cfg.multiview.depth
        + (cfg.fusion.misaligned_correlation > -1)
    )
    prog.plan(1 + len(images) * len(REFERENCE_STAGES) + steps + 2)
    with prog.stage("check inputs"):
        ctx = prepare_fill(target, mask, images, cfg, target_exif, prog.say, prog.detail)
    refs = []
    for i, (s, e, m) in enumerate(zip(images, exifs, masks, strict=True)):
        source = as_rgb_uint8(s)
        exclude = None if m is None else as_source_mask(m, source, f"mask of source {i + 1}")
        name = source_names[i] if source_names is not None else ""
        refs.append(ReferenceArtifacts(i + 1, source, e, exclude, name=name))
    refs, across = run_all_references(ctx, refs, prog)
    with prog.stage("fuse") as notes:
        fusion = fuse_references(ctx.target, ctx.hole, [r for r in refs if r.usable], cfg)
        notes.append(fusion.summary())
    with prog.stage("composite") as notes:
        # The depth is only read by a painter that paints by planes (``inpaint.planes``).
        depth = scene_depth(ctx, [r for r in refs if r.usable]) if ctx.inpainter.run_depth else None
        image = composite(ctx, fusion, depth)
        notes.append(f"single-image inpainting: {ctx.inpainter.description}")
    report = _report(ctx, refs, fusion, prog)
    report.registration = across.registration
    if across.multiview is not None:
        report.multiview = across.multiview.report()
    report.wall_s = prog.wall_s() - started
    if report.status == "single_image":
        prog.say("no reference photo could be used: the whole hole was painted from its surroundings")
    return FillResult(image, report, refs, fusion, fusion.source_map(ctx.hole))


def fill_loaded(
    target: LoadedImage,
    hole: np.ndarray,
    sources: Sequence[LoadedImage],
    config: FillConfig | None = None,
    *,
    source_masks: Sequence[np.ndarray | None] | None = None,
    source_names: Sequence[str] | None = None,
    progress: Progress | None = None,
) -> FillResult:
    """:func:`fill` on images read with :func:`geofill.io.read_image`, each with its EXIF lens: the
    one call the CLI, the batch worker and the server worker make."""
    return fill(
        target.pixels,
        hole,
        [s.pixels for s in sources],
        config,
        target_exif=target.exif,
        source_exifs=[s.exif for s in sources],
        source_masks=source_masks,
        source_names=source_names,
        progress=progress,
    )


def shares_camera(ctx: FillContext, refs: list[ReferenceArtifacts]) -> bool:
    """Whether one focal is estimated for all images (``intrinsics.shared_camera``): several
    references, no focal given by a flag, and the user says so or every EXIF names the same camera."""
    ic = ctx.cfg.intrinsics
    if len(refs) < 2 or ic.estimate == "none" or ic.shared_camera == "no":
        return False
    if ic.focal_px is not None or ic.target is not None or ic.source is not None:
        return False
    if ic.shared_camera == "yes":
        return True
    ids = {getattr(e, "camera_id", None) for e in (ctx.target_exif, *(r.exif for r in refs))}
    return len(ids) == 1 and None not in ids


def shared_focal(refs: list[ReferenceArtifacts], cfg: FillConfig) -> list[ReferenceArtifacts]:
    """Every matched reference given the focal estimated from all pairs together (their focal
    stage then does not run)."""
    live = [r.index for r in refs if r.matches is not None and not r.dropped]
    problems = [
        (r.matches, r.views.K_target, r.views.K_source, r.views.ransac_px) for r in refs if r.index in live
    ]
    candidate = shared_focal_scale(problems, cfg.intrinsics)
    return [
        replace(r, focal=shared_estimate(candidate, r.views.K_target, r.views.K_source))
        if r.index in live
        else r
        for r in refs
    ]


def one_camera(refs: list[ReferenceArtifacts]) -> bool:
    """Whether the target and these references look like one camera to the joint registration:
    the same working size and the same focal prior (all default, or one EXIF focal)."""
    views = [r.views for r in refs if r.views is not None]
    priors = {(K.width, K.height, K.fx, K.origin) for v in views for K in (v.K_target, v.K_source)}
    return len(priors) == 1


def joint_input(ctx: FillContext, refs: list[ReferenceArtifacts]) -> JointDatabase | None:
    """The joint registration's features of the target and every prepared reference (after the
    ``prepare`` stage for COLMAP's own, after ``match`` for the match stage's); None where fewer
    than two references can take part."""
    cfg = ctx.cfg
    own = cfg.registration.features == "matching"
    live = _joint_live(refs, own)
    if len(live) < 2:
        return None
    features = [_sift_of(live[0])[0]] + [_sift_of(r)[1] for r in live] if own else None
    first = live[0].views
    return extract_joint(
        first.target_gray, first.hole, [r.views.source_gray for r in live], one_camera(live),
        cfg.registration.max_features, cfg.registration.max_side, features,
    )  # fmt: skip


def _joint_live(refs: list[ReferenceArtifacts], own_features: bool) -> list[ReferenceArtifacts]:
    return [r for r in refs if r.views is not None and (not own_features or _sift_of(r) is not None)]


def joint_registration(
    ctx: FillContext, refs: list[ReferenceArtifacts], extracted: Future | None = None
) -> tuple[list[ReferenceArtifacts], str]:
    """Every reference with a per-pair focal and pose that the joint registration
    (:mod:`geofill.joint`) places together with the target, and whose own matches its geometry
    explains about as well as the per-pair focal and pose do, given COLMAP's focal and pose; the
    others keep the per-pair ones. Also the line saying what happened. ``extracted``: the pending
    :func:`joint_input` started before the pairs were matched (else it runs here)."""
    cfg = ctx.cfg
    if not joint_available():
        return (
            refs,
            f"registered pair by pair: registering several references together needs the 'sfm' extra "
            f"({install_hint('pycolmap')})",
        )
    db = extracted.result() if extracted is not None else joint_input(ctx, refs)
    if db is None:
        return refs, "per-pair registration: fewer than two references were prepared"
    live = _joint_live(refs, cfg.registration.features == "matching")
    estimated = [r.focal.K_target.fx for r in live if r.focal is not None]
    f_t = float(np.median(estimated)) if estimated else live[0].views.K_target.fx
    if one_camera(live):
        # One camera for all, from the pairs' median: seeding each image with its own pair's
        # estimate split the camera on fox upper (focal 514-983 px) and COLMAP misplaced a reference by 9 deg.
        f_s = [f_t] * len(live)
    else:
        f_s = [r.focal.K_source.fx if r.focal is not None else r.views.K_source.fx for r in live]
    cams = register_joint(db, f_t, f_s, cfg.fusion.parallel)
    cam_of = {r.index: c for r, c in zip(live, cams, strict=True)}
    out, placed, refused = [], [], []
    for r in refs:
        cam = cam_of.get(r.index)
        if cam is None or r.pose is None or r.dropped:
            out.append(r)
            continue
        v = r.views
        joint = joint_focal(cam, v.K_target, v.K_source, v.K_target.width, v.K_source.width)
        conflict = prior_conflict(joint, cfg.intrinsics)
        pose = (
            None
            if conflict
            else joint_pose(cam, r.matches, joint.K_target, joint.K_source, v.ransac_px, cfg.geometry)
        )
        n_joint = 0 if pose is None else int(pose.inliers.sum())
        n_own = int(agreeing(r.pose.T, r.matches, r.focal.K_target, r.focal.K_source, v.ransac_px).sum())
        if conflict or n_joint < max(cfg.geometry.min_inliers, cfg.registration.min_agreement * n_own):
            why = (
                conflict
                or f"its matches agree with the joint pose {n_joint}x, with the per-pair one {n_own}x"
            )
            refused.append((r.index, f"reference {r.index}: {why}"))
            out.append(r)
            continue
        baseline = float(np.linalg.norm(cam.T[:3, 3])) if pose.status == "ok" else None
        out.append(replace(r, focal=joint, pose=pose, joint_baseline=baseline))
        placed.append((r.index, f"{r.index} ({n_joint} matches agree, {n_own} with the per-pair pose)"))
    refused, placed = [text for _, text in sorted(refused)], [text for _, text in sorted(placed)]
    why = f" (per-pair kept for {'; '.join(refused)})" if refused else ""
    if not placed:
        return out, f"COLMAP registered no usable reference with the target: per-pair registration{why}"
    return out, f"COLMAP registered reference(s) {', '.join(placed)} of {len(refs)} with the target{why}"


def _sift_of(ref: ReferenceArtifacts) -> tuple[Features, Features] | None:
    """The target's and the source's SIFT keypoints from ``ref``'s match stage (None before it)."""
    m = ref.matches
    if m is None or m.target_features is None or m.source_features is None:
        return None
    return m.target_features, m.source_features


def multiview_step(
    refs: list[ReferenceArtifacts], cfg: FillConfig
) -> tuple[list[ReferenceArtifacts], MultiViewDepth]:
    """Every reference with geometry given its hole footprint's depth measured from the others
    (:func:`geofill.multiview.multiview_depth`)."""
    # The first reference anchors the common frame (every other one's scale is measured against its
    # depth): the one with the most pose inliers, not whichever the user listed first.
    live = sorted(
        (r for r in refs if r.geometry is not None and not r.dropped),
        key=lambda r: r.pose.n_inliers,
        reverse=True,
    )  # stable: ties keep the canonical order
    geometries, result = multiview_depth(
        [ViewGeometry(r.index, r.views, r.geometry, r.points, r.joint_baseline) for r in live],
        cfg.multiview,
        cfg.fusion.parallel,
    )
    new = {r.index: g for r, g in zip(live, geometries, strict=True)}
    result = replace(result, references=tuple(sorted(result.references, key=lambda m: m.index)))
    return [replace(r, geometry=new[r.index]) if r.index in new else r for r in refs], result


@dataclass(frozen=True)
class AcrossReferences:
    """What the steps across several references did: how the cameras were registered (plain words,
    "" with one reference or before the pose stage) and the multi-view depth (None where it did not run)."""

    registration: str = ""
    multiview: MultiViewDepth | None = None


def run_all_references(
    ctx: FillContext, refs: list[ReferenceArtifacts], prog: Progress, until: str | None = None
) -> tuple[list[ReferenceArtifacts], AcrossReferences]:
    """Every reference through its stages up to ``until`` (all by default) as :func:`fill` runs
    them, with the steps across references where their stage has passed: one focal for a shared
    camera after ``match``, the joint registration after ``pose``, the multi-view depth after
    ``optimize``. The references run in :func:`canonical_order` and come back in the order given."""
    given = [r.index for r in refs]
    refs = canonical_order(refs)
    cfg = ctx.cfg
    names = [s for s, _ in REFERENCE_STAGES]
    last = names.index(until) if until is not None else len(names) - 1

    def past(stage: str) -> bool:
        return last > names.index(stage)

    many = len(refs) > 1
    joint = many and cfg.registration.joint == "auto" and past("pose")
    with ThreadPoolExecutor(1, thread_name_prefix="joint") as background:
        extracted = None
        colmap_features = cfg.registration.features == "colmap"
        if joint and joint_available() and colmap_features and cfg.fusion.parallel > 1:
            # COLMAP's own features need only the prepared images: extracted while the pairs are
            # matched (COLMAP releases the GIL), they take the time a core would idle. Not with one
            # thread asked for (a batch runs one fill per core).
            refs = _run_references(ctx, refs, prog, until="prepare")
            extracted = background.submit(joint_input, ctx, refs)
        refs, registration = _registered(ctx, refs, prog, past, joint, extracted)
    multiview = None
    if many and cfg.multiview.depth and past("optimize"):
        refs = _run_references(ctx, refs, prog, until="optimize")
        with prog.stage("multi-view depth") as notes:
            refs, multiview = multiview_step(refs, cfg)
            notes.append(multiview.summary())
    if many and ctx.shown is not None and last >= names.index("render"):
        refs = _run_references(ctx, refs, prog, until="render")
        with prog.stage("removed object") as notes:
            refs = object_step(ctx, refs)
            found = sum(
                r.render is not None and r.render.located is not None and r.render.located.located
                for r in refs
            )
            notes.append(f"located in {found} of {len(refs)} references")
    if many and past("render") and cfg.fusion.misaligned_correlation > -1:
        refs = _run_references(ctx, refs, prog, until="render")
        with prog.stage("line-up") as notes:
            refs, summary = lineup_step(ctx, refs, prog)
            notes.append(summary)
    done = {r.index: r for r in _run_references(ctx, refs, prog, until=until)}
    return [done[i] for i in given], AcrossReferences(registration, multiview)


def lineup_step(
    ctx: FillContext, refs: list[ReferenceArtifacts], prog: Progress
) -> tuple[list[ReferenceArtifacts], str]:
    """The rendered references whose render does not line up with the photo around the hole while
    another's does (:mod:`geofill.fuse.lineup`) dropped before refinement; and each one's ring
    correlation."""
    lineups = {
        r.index: ring_correlation(r.render.render, r.source, ctx.target, ctx.hole)
        for r in refs
        if r.render is not None and not r.dropped
    }
    drop = misaligned(lineups, ctx.cfg.fusion)
    after_render = len(REFERENCE_STAGES) - [s for s, _ in REFERENCE_STAGES].index("render") - 1
    out = []
    for r in refs:
        if r.index in drop:
            r = replace(r, dropped=drop[r.index], dropped_at="line-up")
            prog.detail(f"reference {r.index} cannot help: {r.dropped}")
            prog.say(f"{_label(r.index, r.name)} was not used: {r.dropped_words}")
            prog.advance(after_render)  # the stages it will not run
        out.append(r)
    summary = ", ".join(f"reference {i} {lu.correlation:.2f}" for i, lu in sorted(lineups.items()))
    return out, f"ring correlation {summary}" if lineups else "no render"


def canonical_order(refs: Sequence[ReferenceArtifacts]) -> list[ReferenceArtifacts]:
    """``refs`` ordered by their content (pixels, then reference mask), so that the order the user
    lists them in cannot change the fill: the shared focal, the joint registration and the
    multi-view depth all take them in list order."""

    def digest(a: np.ndarray | None) -> bytes:
        if a is None:
            return b""
        # The buffer itself: tobytes() would copy each source image first.
        return hashlib.blake2b(np.ascontiguousarray(a).data, digest_size=16).digest()

    return sorted(refs, key=lambda r: (digest(r.source), digest(r.exclude)))


def _registered(
    ctx: FillContext,
    refs: list[ReferenceArtifacts],
    prog: Progress,
    past: Callable[[str], bool],
    joint: bool,
    extracted: Future | None,
) -> tuple[list[ReferenceArtifacts], str]:
    """:func:`run_all_references` up to the registration: one focal for a shared camera after
    ``match``, then, when ``joint``, the joint registration after ``pose``; and the line saying how
    the references were registered."""
    cfg, many = ctx.cfg, len(refs) > 1
    if past("match"):
        if shares_camera(ctx, refs):
            refs = _run_references(ctx, refs, prog, until="match")
            with prog.stage("shared focal") as notes:
                refs = shared_focal(refs, cfg)
                notes.append(next((r.focal.summary() for r in refs if r.focal is not None), "no usable pair"))
            prog.advance(sum(r.focal is not None for r in refs))  # their focal stage will not run
        else:
            prog.advance(many)
    registration = "per pair (registration.joint=off)" if many and past("pose") else ""
    if joint:
        refs = _run_references(ctx, refs, prog, until="pose")  # the per-pair ones, to compare
        with prog.stage("joint registration") as notes:
            refs, registration = joint_registration(ctx, refs, extracted)
            notes.append(registration)
        if not joint_available():  # the default asks for it: the user hears what installs it
            prog.say(registration)
    return refs, registration


def _run_references(
    ctx: FillContext, refs: list[ReferenceArtifacts], prog: Progress, until: str | None = None
) -> list[ReferenceArtifacts]:
    """Every reference through its stages (up to ``until``), ``fusion.parallel`` at a time. Each
    gets its own progress (prefixed with its number when there are several) so timings never mix."""
    many = len(refs) > 1

    def one(ref: ReferenceArtifacts) -> ReferenceArtifacts:
        sub = prog.child(f"ref {ref.index}") if many else prog.child("")
        return run_reference(ctx, ref, sub, until=until)

    workers = max(1, min(ctx.cfg.fusion.parallel, len(refs)))
    if workers == 1:
        return [one(r) for r in refs]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(one, refs))


def composite(ctx: FillContext, fusion: Fusion, depth: SceneDepth | None = None) -> np.ndarray:
    """The fused render inside the hole where it exists, single-image inpainting for the rest,
    merged with a feathered blending map (:func:`geofill.composite.merge.merge_fill`); pixels outside the
    hole are copied from the target unchanged. ``depth``: the target's, for the painter's planes."""
    feather = config_px(ctx.cfg.refine.feather_px, ctx.hole.shape)
    return merge_fill(ctx.target, ctx.hole, fusion.image, fusion.alpha, ctx.inpainter, feather, depth)


def scene_depth(ctx: FillContext, refs: list[ReferenceArtifacts]) -> SceneDepth | None:
    """The target's depth around the hole from the reference whose render covers most of the
    image (its target-view depth, in its own pose units: planes do not depend on the scale), with
    the target's intrinsics at its size; None without a render."""
    best, count = None, 0
    for r in refs:
        if r.render is None or r.intrinsics() is None:
            continue
        depth = r.render.render.depth
        n = int(np.count_nonzero(np.isfinite(depth[r.render.render.window()])))
        if n > count:
            best, count = r, n
    if best is None:
        return None
    h, w = ctx.hole.shape
    return SceneDepth(best.render.render.depth, best.intrinsics()[0].resized(w, h).K)


#: Why a painted hole pixel was not copied, in the order a pixel with several reasons is counted
#: under (the user's own mask first); each name is a ``ScreenedRender``/``Fusion`` field.
_REFUSALS = (
    ("masked", "refused_masked"),
    ("removed_object", "refused_object"),
    ("stranger", "refused_stranger"),
    ("mismatch", "refused_mismatch"),
)


def _refused_fractions(hole: np.ndarray, used: list[ReferenceArtifacts], fusion: Fusion) -> dict[str, float]:
    """Of the hole, the painted pixels (no reference supplies them) broken down by why: a reason
    where some reference's render covered the pixel but was refused there (the first of
    :data:`_REFUSALS` that applies; the fuse stage's refusals of a reference the others contradict
    count as strangers), ``unseen`` where no reference's render covers it. The parts are disjoint
    and add up to the painted fraction; a reason is listed (0 where nothing was refused) wherever
    its test ran."""
    n = max(int(hole.sum()), 1)
    left = hole & ~(fusion.labels > 0)
    out = {}
    for key, name in _REFUSALS:
        masks = [getattr(r.screened, name, None) for r in used]
        masks = [m for m in [*masks, getattr(fusion, name, None)] if m is not None]
        if masks:
            mine = np.logical_or.reduce(masks) & left
            out[key] = float(np.count_nonzero(mine)) / n
            left &= ~mine
    if used:
        out["unseen"] = float(np.count_nonzero(left)) / n
    return out


def _report(ctx: FillContext, refs: list[ReferenceArtifacts], fusion: Fusion, prog: Progress) -> FillReport:
    supplied = fusion.supplied_fractions(ctx.hole, len(refs))
    used = [r for r in refs if r.usable]
    fallbacks = [f"reference {r.index}: {r.dropped}" for r in refs if r.dropped]
    for r in used:
        if r.geometry.thin:
            fallbacks.append(f"reference {r.index}: initial geometry kept: {r.geometry.skipped}")
        opt = r.geometry.optimization
        if opt is not None and opt.status == "rejected":
            fallbacks.append(
                f"reference {r.index}: optimisation rejected, initial geometry kept: {opt.reason}"
            )
        if r.pose.status == "rotation_only":
            fallbacks.append(f"reference {r.index}: {r.pose.reason}")
    return FillReport(
        status="reference" if used and sum(supplied) > 0 else "single_image",
        fallbacks=fallbacks,
        hole_pixels=int(ctx.hole.sum()),
        references=[r.report() for r in refs],
        supplied_fraction=supplied,
        painted_fraction=1.0 - float(sum(supplied)),
        refused_fraction=_refused_fractions(ctx.hole, used, fusion),
        disputed_fraction=fusion.disputed_fractions(ctx.hole, len(refs)),
        fusion=fusion.report(),
        inpaint_method=ctx.inpainter.description,
        depth_choice=ctx.depth_choice.reason,
        timings_s=dict(prog.timings),
    )
