"""Would a "more scales" rung pay? SIFT on each image resized by a factor pair (target, source),
matched with the loose rung's ratio and verified as strictly, against what the ladder's own rungs
verify, on the pairs where plain SIFT is weak (100-px brush holes, seed 0).

    .venv/bin/python benchmarks/studies/more_scales.py [--pairs DIR ...]

Prints verified matches and seconds per factor pair next to the ladder's result. Figures, not a test.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.match import match_pair
from geofill.match.features import detect_sift, keypoint_mask, mutual_ratio_matches, to_gray_u8
from geofill.match.ladder import verify_fundamental
from geofill.prepare import prepare_views

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

FACTORS = ((1.0, 0.5), (0.5, 1.0), (1.0, 0.7), (0.7, 1.0), (0.5, 0.5), (1.0, 1.4), (1.4, 1.0))


def _sift_at(gray: np.ndarray, mask: np.ndarray | None, f: float, n: int):
    """SIFT of ``gray`` resized by ``f``, positions in the original pixels."""
    size = (round(gray.shape[1] * f), round(gray.shape[0] * f))
    g = cv2.resize(gray, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR)
    m = None if mask is None else cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)
    feats = detect_sift(g, n, m)
    return (feats.pts + 0.5) / f - 0.5, feats.desc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--pairs", action="append", help="pair folder(s) (default: every DEV pair where SIFT is weak)"
    )
    args = ap.parse_args(argv)
    cfg = FillConfig()
    mc = cfg.matching
    for pair in load_pairs(args.pairs or [str(PAIRS)], exclude=HELD_OUT):
        hole = pair_mask(pair, 0, 100.0)
        views = prepare_views(pair.target, hole, pair.source, cfg, pair.exif.target, pair.exif.source)
        target = views.target.copy()
        target[views.hole] = 0
        t0 = time.perf_counter()
        ladder = match_pair(target, views.source, views.hole, mc, views.px_scale)
        ladder_s = time.perf_counter() - t0
        if ladder.rung == "sift" and args.pairs is None:
            continue  # plain SIFT verified: no rung would run
        gray_t, gray_s = to_gray_u8(target), to_gray_u8(views.source)
        mask_t = keypoint_mask(views.hole, mc.hole_margin_px * views.px_scale)
        strict = mc.ransac_px(views.px_scale) * mc.strict_threshold_scale
        print(f"{pair.id}: ladder {ladder.rung} {len(ladder)} verified in {ladder_s:.2f} s")
        for ft, fs in FACTORS:
            t0 = time.perf_counter()
            pt, dt = _sift_at(gray_t, mask_t, ft, mc.max_features)
            ps, ds = _sift_at(gray_s, None, fs, mc.max_features)
            ij = mutual_ratio_matches(dt, ds, mc.loose_ratio, False)
            F, inl = verify_fundamental(pt[ij[:, 0]], ps[ij[:, 1]], strict, mc)
            n = int(inl.sum()) if F is not None else 0
            took = time.perf_counter() - t0
            print(f"  target x{ft:.1f} source x{fs:.1f}: {n:4d} verified of {len(ij):5d} in {took:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
