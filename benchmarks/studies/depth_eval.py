"""Depth accuracy per backend, as the fill sees it (the paper's supplement depth table).

For each pair with exact depth (synthetic scenes) or GT depth (``depth_source.png`` of the real
pairs), the whole pipeline runs with the evaluation hole (``geofill eval``'s brush strokes) and each
depth backend; its aligned source depth (pose units, after the pipeline's own scale/offset) is
brought to GT units with the GT baseline and scored against GT: AbsRel, RMS-log and delta<1.25,
over all valid pixels and over the source pixels whose GT 3D point projects into the target hole
(the ones the fill needs). Also printed: the hole PSNR of the fill and, for ``stereo``, the fraction
of source pixels the sweep was confident about.

    .venv/bin/python benchmarks/studies/depth_eval.py [--synthetic N] [--true-intrinsics]
        [--backends sparse,stereo]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from geofill.camera import Intrinsics
from geofill.config import FillConfig
from geofill.depth import DepthContext, get_backend
from geofill.depth.onnx import resolve_model
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import Pair, load_pairs, pair_mask
from geofill.pipeline import fill
from geofill.render import project_source_grid
from geofill.synthetic import make_pair
from geofill.weights import WeightsUnavailable

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS


@dataclass
class Case:
    """A pair with GT: source depth (GT units, 0/NaN invalid), GT intrinsics and pose."""

    pair: Pair
    depth: np.ndarray
    K_source: np.ndarray
    K_target: np.ndarray
    T: np.ndarray


def synthetic_cases(n: int) -> list[Case]:
    cases = []
    for i in range(n):
        sp = make_pair(seed=i)
        pair = Pair(f"synthetic_{i:03d}", sp.target, [sp.source], {"kind": "synthetic"}, None)
        cases.append(Case(pair, sp.depth_source, sp.K_source, sp.K_target, sp.T_source_to_target))
    return cases


def real_cases() -> list[Case]:
    if not PAIRS.is_dir():
        return []
    cases = []
    for pair in load_pairs([PAIRS], exclude=HELD_OUT):
        if pair.path is None or not (pair.path / "depth_source.png").is_file():
            continue
        gt = cv2.imread(str(pair.path / "depth_source.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        T = pair.meta.get("T_source_to_target") or pair.meta.get("T_source_to_target_estimated")
        K_s, K_t = (np.array(pair.meta[k], dtype=np.float64) for k in ("K_source", "K_target"))
        cases.append(Case(pair, gt, K_s, K_t, np.array(T, dtype=np.float64)))
    return cases


def depth_scores(pred: np.ndarray, gt: np.ndarray, where: np.ndarray) -> tuple[float, float, float, int]:
    """(AbsRel, RMS-log, delta<1.25, n) over ``where`` & valid GT & positive prediction."""
    ok = where & np.isfinite(pred) & (pred > 0) & np.isfinite(gt) & (gt > 0)
    n = int(ok.sum())
    if n == 0:
        return float("nan"), float("nan"), float("nan"), 0
    p, g = pred[ok].astype(np.float64), gt[ok].astype(np.float64)
    ratio = p / g
    return (
        float(np.mean(np.abs(p - g) / g)),
        float(np.sqrt(np.mean(np.log(ratio) ** 2))),
        float(np.mean(np.maximum(ratio, 1 / ratio) < 1.25)),
        n,
    )


def hole_pixels(case: Case, hole: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w) bool at source size ``size`` (w, h): GT point of the source pixel lands in ``hole``."""
    h0, w0 = case.depth.shape
    K_s = Intrinsics.from_matrix(case.K_source, w0, h0).resized(*size)
    H, W = hole.shape
    K_t = Intrinsics.from_matrix(case.K_target, W, H)
    gt = cv2.resize(case.depth, size, interpolation=cv2.INTER_NEAREST)
    u, v, z = project_source_grid(np.where(gt > 0, gt, np.nan), K_s, K_t, case.T)
    ui, vi = np.rint(np.nan_to_num(u, nan=-1)), np.rint(np.nan_to_num(v, nan=-1))
    inside = (z > 0) & (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    out = np.zeros(gt.shape, bool)
    out[inside] = hole[vi[inside].astype(int), ui[inside].astype(int)]
    return out


def confident_fraction(res, cfg: FillConfig) -> float:
    """Share of source pixels the stereo sweep was confident about (re-runs the backend)."""
    a = res.references[0]
    v, K = a.views, a.focal
    ctx = DepthContext(
        v.source, v.target, v.hole, K.K_source, K.K_target, a.pose, a.points, (0, 0), cfg.depth
    )
    pred = get_backend("stereo").predict(ctx)
    return float((pred.confidence >= cfg.depth.stereo_min_confidence).mean())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--synthetic", type=int, default=6, help="number of synthetic scenes (seeds 0..N-1)")
    ap.add_argument("--no-real", action="store_true", help="skip the real GT-depth pairs")
    ap.add_argument("--true-intrinsics", action="store_true", help="give the pipeline the GT intrinsics")
    ap.add_argument("--backends", default="sparse,stereo,onnx,fused", help="comma-separated depth backends")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    args = ap.parse_args()
    from geofill.config import parse_overrides

    base = FillConfig().updated(parse_overrides(args.set))
    cases = synthetic_cases(args.synthetic) + ([] if args.no_real else real_cases())
    backends = []
    for name in args.backends.split(","):
        weights = resolve_model(base.depth) if name in ("onnx", "fused") else None
        if isinstance(weights, WeightsUnavailable):
            print(f"{name}: not measured: {weights}")
        else:
            backends.append(name)
    head = f"{'pair':<34s} {'backend':<8s} {'AbsRel':>7s} {'RMSlog':>7s} {'d<1.25':>7s}"
    head += f" | {'hAbsRel':>7s} {'hRMSlog':>7s} {'hd<1.25':>7s} {'n_hole':>7s} | {'PSNRh':>6s} {'conf':>5s}"
    print(head)
    rows: dict[tuple[str, str], list[list[float]]] = {}
    for case in cases:
        pair = case.pair
        hole = pair_mask(pair, 0)
        kind = "synthetic" if pair.path is None else "real"
        baseline = float(np.linalg.norm(case.T[:3, 3]))
        for name in backends:
            overrides: dict = {"depth.backend": name}
            if args.true_intrinsics:
                ks, kt = ([K[0, 0], K[1, 1], K[0, 2], K[1, 2]] for K in (case.K_source, case.K_target))
                overrides |= {"intrinsics.source": ks, "intrinsics.target": kt}
            cfg = base.updated(overrides)
            masked = np.where(hole[..., None], 0, pair.target).astype(np.uint8)  # as `geofill eval` does
            res = fill(masked, hole, pair.source, cfg)
            p = psnr(res.image, pair.target, hole)
            if res.references[0].depth is None:
                print(f"{pair.id:<34s} {name:<8s} failed: {res.report.fallbacks}")
                continue
            pred = res.references[0].depth.depth * baseline
            h, w = pred.shape
            gt = cv2.resize(case.depth, (w, h), interpolation=cv2.INTER_NEAREST)
            gt = np.where(gt > 0, gt, np.nan)
            all_px = depth_scores(pred, gt, np.ones_like(gt, bool))
            in_hole = depth_scores(pred, gt, hole_pixels(case, hole, (w, h)))
            conf = confident_fraction(res, cfg) if name == "stereo" else float("nan")
            vals = [*all_px[:3], *in_hole[:3], p, conf]
            rows.setdefault((kind, name), []).append(vals)
            print(
                f"{pair.id:<34s} {name:<8s} {all_px[0]:7.3f} {all_px[1]:7.3f} {all_px[2]:7.3f} | "
                f"{in_hole[0]:7.3f} {in_hole[1]:7.3f} {in_hole[2]:7.3f} {in_hole[3]:7d} | "
                f"{p:6.2f} {conf:5.2f}",
                flush=True,
            )
    print("\nmean per set and backend:")
    for (kind, name), vals in rows.items():
        a = np.nanmean(np.array(vals, dtype=np.float64), axis=0)
        print(
            f"  {kind:<9s} {name:<8s} AbsRel {a[0]:.3f} RMSlog {a[1]:.3f} d<1.25 {a[2]:.3f} | "
            f"hole: AbsRel {a[3]:.3f} RMSlog {a[4]:.3f} d<1.25 {a[5]:.3f} | PSNR hole {a[6]:.2f} dB"
            f" | confident {a[7]:.2f}  (n={len(vals)})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
