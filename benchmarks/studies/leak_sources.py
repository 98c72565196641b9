"""Where the strangers protocol's leak comes from: each leaked hole pixel of the all-reference fill
(``geofill eval --protocol strangers --references all``, same renders as
:mod:`fusion_variants`) put in one class, as a share of the hole's distinguishable pixels (the
leak's denominator, so the classes add up to the leak):

- ``all``: every render covering it (as refined, before the screen) shows a stranger there; of
  those, ``lone``: exactly one render covers it (nothing else sees that place);
- ``chosen``: a render that does not show a stranger covered it after the screen, and the fuse
  stage chose one that does; split by how many screened renders covered it and how many of them
  show a stranger (``c2s1``: two covering, one a stranger);
- ``other``: the rest (painted, or a blend across a seam).

A render pixel "shows a stranger" by the leak's own rule (nearer to a stranger than half its
distance to the truth, where the stranger is distinguishable).

``--oracle`` bounds what any stranger detection could reach in this pipeline: it prints, per set,
hole PSNR / leak of the fill as it is, of the fill whose renders lose every pixel that shows a
stranger (known from the truth, grown by 2 px) before the screen, and of the painter alone.

    .venv/bin/python benchmarks/studies/leak_sources.py --seed 0 --seed 1 [--cache DIR] [--oracle]
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW
from benchmarks.studies.fusion_variants import _renders, screened


def _fill(ctx, refs, hole, truth) -> tuple[list, object, np.ndarray]:
    """``refs`` (refined renders) through the screen, fuse and composite stages: the usable
    screened references, their fusion and the output (the truth outside the hole)."""
    from geofill.fuse import fuse_references
    from geofill.pipeline import composite

    refs = [r for r in screened(ctx, refs, ctx.cfg) if r.usable]
    fusion = fuse_references(ctx.target, hole, refs, ctx.cfg)
    return refs, fusion, np.where(hole[..., None], composite(ctx, fusion), truth)


def classify(ctx, refs, hole, truth, objects) -> Counter:
    """Counts of distinguishable pixels per class (see the module docstring), and ``n``."""
    from geofill.evaluation.metrics import leak_masks

    refs, fusion, output = _fill(ctx, refs, hole, truth)
    leaked, distinguishable = leak_masks(output, truth, objects, hole)
    cover = np.zeros(hole.shape, int)
    strangers = np.zeros(hole.shape, int)
    s_cover = np.zeros(hole.shape, int)
    s_strangers = np.zeros(hole.shape, int)
    chose_stranger = np.zeros(hole.shape, bool)
    for r in refs:
        a = r.refined.alpha & hole
        cover += a
        strangers += leak_masks(r.refined.image, truth, objects, a)[0]
        sa = r.screened.alpha & hole
        s = leak_masks(r.screened.image, truth, objects, sa)[0]
        s_cover += sa
        s_strangers += s
        chose_stranger |= (fusion.labels == r.index) & s
    out = Counter(n=int(distinguishable.sum()), leak=int(leaked.sum()))
    every = leaked & (cover >= 1) & (strangers == cover)
    out["all"] = int(every.sum())
    out["lone"] = int((every & (cover == 1)).sum())
    chosen = leaked & ~every & chose_stranger & (s_strangers < s_cover)
    out["chosen"] = int(chosen.sum())
    for c in range(2, 5):
        for s in range(1, c):
            out[f"c{c}s{s}"] = int((chosen & (s_cover == c) & (s_strangers == s)).sum())
    out["other"] = out["leak"] - out["all"] - out["chosen"]
    return out


def oracle(ctx, refs, hole, truth, objects) -> list[tuple[float, float]]:
    """(hole PSNR, leak) of the fill as it is, with every stranger pixel taken out of the renders
    (known from the truth), and painted alone (every render's hole pixels taken out)."""
    import cv2

    from geofill.evaluation.metrics import leak, leak_masks, psnr

    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))

    def without(drop) -> list:
        out = []
        for r in refs:
            if r.refined is None:  # dropped before the render
                out.append(r)
                continue
            gone = drop(r)
            alpha = r.refined.alpha & ~gone
            image = np.where(alpha[..., None], r.refined.image, 0).astype(np.uint8)
            out.append(replace(r, refined=replace(r.refined, image=image, alpha=alpha)))
        return out

    def stranger(r) -> np.ndarray:
        shows = leak_masks(r.refined.image, truth, objects, r.refined.alpha & hole)[0]
        return cv2.dilate(shows.astype(np.uint8), grow).astype(bool)

    scored = []
    for variant in (refs, without(stranger), without(lambda r: hole)):
        image = _fill(ctx, variant, hole, truth)[2]
        scored.append((psnr(image, truth, hole), leak(image, truth, objects, hole).fraction or 0.0))
    return scored


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, action="append", default=None, help="protocol seed (repeatable)")
    ap.add_argument("--pairs", action="append", default=None, help=f"as geofill eval's (default {MULTIVIEW})")
    ap.add_argument("--cache", type=Path, help="folder keeping the renders between runs")
    ap.add_argument("--oracle", action="store_true", help="the fills without the strangers' pixels instead")
    args = ap.parse_args(argv)
    if args.oracle:
        return main_oracle(args)
    keys = ["leak", "all", "lone", "chosen", "c2s1", "c3s1", "c3s2", "c4s1", "c4s2", "c4s3", "other"]
    print("| seed | set | " + " | ".join(keys) + " |")
    print("|" + " --- |" * (len(keys) + 2))
    rows = []
    for seed in args.seed or [0]:
        for set_id, ctx, refs, hole, truth, objects in _renders(
            args.pairs or [str(MULTIVIEW)], "strangers", args.cache, seed
        ):
            c = classify(ctx, refs, hole, truth, objects)
            row = [c[k] / max(c["n"], 1) for k in keys]
            rows.append(row)
            cells = " | ".join(f"{v:.3f}" for v in row)
            print(f"| {seed} | {set_id.removeprefix('dev_mv_')} | {cells} |", flush=True)
    mean = " | ".join(f"**{v:.3f}**" for v in np.mean(rows, axis=0))
    print(f"| | **mean** | {mean} |")
    return 0


def main_oracle(args) -> int:
    """``--oracle``'s table: hole PSNR / leak per set and seed, and their means."""
    print("| seed | set | as is | strangers known | painted |")
    print("| --- | --- | --- | --- | --- |")
    rows = []
    for seed in args.seed or [0]:
        for set_id, ctx, refs, hole, truth, objects in _renders(
            args.pairs or [str(MULTIVIEW)], "strangers", args.cache, seed
        ):
            rows.append(oracle(ctx, refs, hole, truth, objects))
            cells = " | ".join(f"{p:.2f} / {k:.3f}" for p, k in rows[-1])
            print(f"| {seed} | {set_id.removeprefix('dev_mv_')} | {cells} |", flush=True)
    mean = np.mean(rows, axis=0)
    print("| | **mean** | " + " | ".join(f"**{p:.2f} / {k:.3f}**" for p, k in mean) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
