"""Depth accuracy in each reference's hole footprint before and after the multi-view depth stage,
on the multi-reference sets with ground-truth depth for every reference.

    .venv/bin/python benchmarks/studies/multiview_depth.py [--sets DIR] [--seeds 0,1,2] [--set KEY=VALUE]

Per set, seed (the evaluation's brush-stroke hole) and reference: the references run to ``optimize``
together (as :func:`geofill.pipeline.fill` runs them), then the stage. The footprint is where the
reference's depth before the stage puts its pixels in the target's hole (the pixels the stage
re-estimates). Each depth (pose units) is fitted to the GT depth by its median ratio over the
footprint; printed: delta < 1.25 (share of pixels within a factor 1.25), AbsRel, and the fraction of
the footprint the stage measured (its report).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW


def accuracy(
    depth: np.ndarray, gt: np.ndarray, region: np.ndarray, scale: float | None = None
) -> tuple[float, float, int]:
    """(delta < 1.25, AbsRel, pixels) of ``depth`` times ``scale`` (default: fitted to ``gt`` by the
    median ratio over ``region``)."""
    ok = region & np.isfinite(depth) & (depth > 0) & (gt > 0)
    if not ok.any():
        return float("nan"), float("nan"), 0
    d = depth[ok] * (np.median(gt[ok] / depth[ok]) if scale is None else scale)
    ratio = np.maximum(d / gt[ok], gt[ok] / d)
    return float(np.mean(ratio < 1.25)), float(np.mean(np.abs(d - gt[ok]) / gt[ok])), int(ok.sum())


def main(argv: list[str] | None = None) -> int:
    from geofill.config import FillConfig, parse_overrides
    from geofill.evaluation.pairs import load_pair, pair_geometry, pair_mask
    from geofill.multiview import ViewGeometry, footprint_crop
    from geofill.pipeline import ReferenceArtifacts, multiview_step, prepare_fill, run_all_references
    from geofill.progress import Progress
    from geofill.synthetic import blanked

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=str(MULTIVIEW))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    cfg = FillConfig().updated(parse_overrides(args.set))
    rows = []
    for folder in sorted(p for p in Path(args.sets).iterdir() if p.is_dir()):
        pair = load_pair(folder)
        gts = pair_geometry(pair).depth_sources
        if not gts or any(d is None for d in gts):
            continue
        for seed in (int(s) for s in args.seeds.split(",")):
            hole = pair_mask(pair, seed)
            ctx = prepare_fill(blanked(pair.target, hole), hole, pair.sources, cfg)
            refs = [ReferenceArtifacts(i + 1, s) for i, s in enumerate(pair.sources)]
            refs, _ = run_all_references(ctx, refs, Progress(quiet=True), until="optimize")
            after, mv = multiview_step(refs, cfg)
            measured = {r.index: r.measured_fraction for r in mv.references}
            for r0, r1 in zip(refs, after, strict=True):
                if r0.geometry is None:
                    continue
                h, w = r0.geometry.depth.shape
                gt = cv2.resize(gts[r0.index - 1], (w, h), interpolation=cv2.INTER_NEAREST)
                crop = footprint_crop(ViewGeometry(r0.index, r0.views, r0.geometry, r0.points), 1.0, 0)
                foot = np.zeros((h, w), bool)
                if crop is not None:
                    fh, fw = crop.footprint.shape
                    foot[crop.y0 : crop.y0 + fh, crop.x0 : crop.x0 + fw] = crop.footprint
                before = accuracy(r0.geometry.depth, gt, foot)
                now = accuracy(r1.geometry.depth, gt, foot)
                # Where the stage changed the depth, with the scale fitted over the whole footprint.
                changed = foot & (r1.geometry.depth != r0.geometry.depth)
                geos = (r0.geometry, r1.geometry)
                fits = [float(np.nanmedian(np.where(foot & (gt > 0), gt / g.depth, np.nan))) for g in geos]
                on_changed = [accuracy(g.depth, gt, changed, s) for g, s in zip(geos, fits, strict=True)]
                rows.append((before, now))
                print(
                    f"{pair.id} seed {seed} ref {r0.index}: footprint {before[2]} px, measured "
                    f"{100 * measured.get(r0.index, 0.0):.0f}%: delta<1.25 {before[0]:.3f} -> {now[0]:.3f}, "
                    f"AbsRel {before[1]:.3f} -> {now[1]:.3f}; on the {on_changed[0][2]} px changed: "
                    f"delta<1.25 {on_changed[0][0]:.3f} -> {on_changed[1][0]:.3f}",
                    flush=True,
                )
    if rows:
        b, a = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        n = b[:, 2]
        keep = n > 0

        def mean(x: np.ndarray) -> float:
            return float(np.average(x[keep], weights=n[keep]))

        print(
            f"pixel-weighted over {keep.sum()} footprints: delta<1.25 {mean(b[:, 0]):.3f} -> "
            f"{mean(a[:, 0]):.3f}, AbsRel {mean(b[:, 1]):.3f} -> {mean(a[:, 1]):.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
