"""Refinement variants on identical renders: each pair is rendered once (default pipeline up to
the render, refinement off), then every variant refines and merges that same render, so the
comparison is not blurred by run-to-run differences of the earlier stages. Hole PSNR per pair and
variant, the homography baseline on the same hole, and means / wins at the end.

    .venv/bin/python benchmarks/studies/refine_variants.py [--pairs ../shared/data/pairs]
        [--set key=value ...] [--variant NAME:key=value,key=value ...] [--render-cache DIR]

``--render-cache DIR`` stores each pair's render (correspondence field, alpha) and reuses it in
later runs, so separate runs compare refinement settings on the very same renders.

Holes are the evaluation's deterministic brush-stroke masks (seed 0). Figures, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from geofill.composite.inpaint import get_inpainter
from geofill.composite.merge import merge_fill
from geofill.config import FillConfig, parse_overrides
from geofill.evaluation.baselines import BaselineError, homography_fill
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import fill
from geofill.refine import refine_render
from geofill.render import RenderResult

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

#: name -> refine-config overrides (on top of the base config's refine section).
VARIANTS = {
    "none": {"colour": "none", "flow": False, "feather_px": 0.0},
    "feather": {"colour": "none", "flow": False},
    "global": {"colour": "global", "flow": False},
    "gain": {"colour": "gain", "flow": False},
    "poisson": {"colour": "poisson", "flow": False},
    "flow": {"colour": "none", "flow": True},
    "flow+global": {"colour": "global", "flow": True},
    "flow+gain": {"colour": "gain", "flow": True},
    "flow+poisson": {"colour": "poisson", "flow": True},
}


def _parse_variant(text: str) -> tuple[str, dict]:
    name, _, rest = text.partition(":")
    items = [f"{kv}" for kv in rest.split(",") if kv]
    return name, parse_overrides(items)


def _render(pair, masked, hole, cfg: FillConfig, cache: Path | None) -> RenderResult | None:
    """The pair's render with refinement off (None when the pipeline falls back), cached in ``cache``."""
    path = cache / f"{pair.id}.npz" if cache is not None else None
    if path is not None and path.is_file():
        z = np.load(path)
        if not z["ok"]:
            return None
        return RenderResult(z["map_x"], z["map_y"], z["depth"], z["alpha"], tuple(int(v) for v in z["roi"]))
    no_refine = cfg.updated({"refine.colour": "none", "refine.flow": False})
    res = fill(
        masked, hole, pair.source, no_refine, target_exif=pair.exif.target, source_exifs=[pair.exif.source]
    )
    r = res.references[0].render.render if res.report.status == "reference" else None
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        if r is None:
            np.savez(path, ok=False)
        else:
            np.savez(
                path, ok=True, map_x=r.map_x, map_y=r.map_y, depth=r.depth, alpha=r.alpha, roi=np.array(r.roi)
            )
    return r


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default=str(PAIRS))
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="base config override (repeatable)")
    ap.add_argument(
        "--variant", action="append", metavar="NAME:k=v,...", help="refine variants to run instead"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--render-cache", type=Path, metavar="DIR", help="store/reuse each pair's render here")
    args = ap.parse_args(argv)
    base = FillConfig().updated(parse_overrides(args.set))
    variants = dict(_parse_variant(v) for v in args.variant) if args.variant else VARIANTS
    names = ["homography", *variants]
    print(f"{'pair':<34s}" + "".join(f"{n:>14s}" for n in names))
    table: dict[str, list[float]] = {n: [] for n in names}
    seconds: dict[str, list[float]] = {n: [] for n in variants}
    for pair in load_pairs([args.pairs], exclude=HELD_OUT):
        hole = pair_mask(pair, args.seed)
        masked = pair.target.copy()
        masked[hole] = 0
        try:
            table["homography"].append(psnr(homography_fill(masked, hole, pair.source), pair.target, hole))
        except BaselineError:
            table["homography"].append(float("nan"))
        rendered = _render(pair, masked, hole, base, args.render_cache)
        for name, overrides in variants.items():
            cfg = base.updated({f"refine.{k}": v for k, v in overrides.items()})
            t0 = time.perf_counter()
            if rendered is None:
                image = merge_fill(masked, hole, None, None, get_inpainter(cfg.inpaint))
            else:
                ref = refine_render(masked, hole, pair.source, rendered, cfg.refine)
                feather = cfg.refine.feather_px * max(hole.shape) / 1280.0
                image = merge_fill(masked, hole, ref.image, ref.alpha, get_inpainter(cfg.inpaint), feather)
            seconds[name].append(time.perf_counter() - t0)
            assert np.array_equal(image[~hole], pair.target[~hole])
            table[name].append(psnr(image, pair.target, hole))
        print(f"{pair.id:<34s}" + "".join(f"{table[n][-1]:>14.2f}" for n in names), flush=True)
    homo = np.array(table["homography"])
    print(f"{'MEAN':<34s}" + "".join(f"{np.nanmean(table[n]):>14.2f}" for n in names))
    print(f"{'MEDIAN':<34s}" + "".join(f"{np.nanmedian(table[n]):>14.2f}" for n in names))
    wins = [int(np.sum(np.array(table[n]) > homo)) for n in names[1:]]
    print(f"{'wins vs homography':<34s}{'-':>14s}" + "".join(f"{w:>11d}/{len(homo):<2d}" for w in wins))
    print(
        f"{'refine+merge s (median)':<34s}{'':>14s}"
        + "".join(f"{statistics.median(seconds[n]):>14.3f}" for n in variants)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
