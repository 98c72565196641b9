"""Focal-length estimation: accuracy of each method, its effect on the pose and on the fill.

    .venv/bin/python benchmarks/studies/focal_bench.py [--pairs ../shared/data/pairs] [--seeds 3]
                                                       [--skip-synthetic] [--skip-psnr] [--psnr-seeds 0,1,2]
    .venv/bin/python benchmarks/studies/focal_bench.py --curve eth3d,berlin_01_02 [--curve-scales 0.9,1,1.1]

1. Real pairs with ground-truth K (meta.json K_target): true focal, the default prior, each
   method's estimate (intrinsics.estimate = none / search / bougnoux / auto) with its focal error,
   and rotation / translation-direction errors of the pose computed with it (and with the true K)
   on the pairs with a ground-truth pose (TUM's pose is itself estimated: focal only). Matches are
   the pipeline's (working resolution, evaluation hole of seed 0 excluded).
2. Rendered scenes (geofill.synthetic): orbits of 0.5 and 1 unit (4.8 / 9.5 deg of vergence),
   landscape and portrait, true focal 0.5x / 1x / 2x the default, ``--seeds`` seeds each; and the
   degenerate motions (sideways, forward, pure rotation), where the prior must be kept.
3. Whole fills with ``geofill eval``'s masks on every pair: hole PSNR for the fixed focal
   (``geofill_fixed_focal``), the estimate (default), the estimate refined by the joint
   optimisation (``optimize.refine_focal``, ``geofill_refine_focal``), the true K given as
   calibration flags where meta.json has it, and the fixed focal x0.98 / x1.02 (the fill's
   sensitivity to a 2 % focal change). Then, on the GT pairs, the focal error and pose errors of
   the geometry the render used (after the optimisation) for the same configurations.
4. ``--curve`` (only this): hole PSNR of the fixed focal swept over a grid of scales of the default,
   per mask seed, on the named pairs, with the estimated focal (and the true one where known) on the
   same scale: how smooth the fill's PSNR is in the focal, i.e. what a per-pair PSNR difference
   between two focal lengths can tell.

Timings are wall-clock on this machine. Figures, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from geofill.camera import Intrinsics, default_focal_px, pose_errors_deg
from geofill.config import FillConfig
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.focal import estimate_focal
from geofill.match import match_pair
from geofill.pipeline import fill
from geofill.pose import estimate_pose
from geofill.prepare import prepare_views
from geofill.synthetic import make_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

METHODS = ("none", "search", "bougnoux", "auto")
CFG = FillConfig()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default=str(PAIRS))
    ap.add_argument("--seeds", type=int, default=3, help="synthetic seeds per configuration")
    ap.add_argument("--skip-synthetic", action="store_true")
    ap.add_argument("--skip-psnr", action="store_true", help="skip the hole-PSNR comparison (slow)")
    ap.add_argument("--psnr-seeds", default="0", help="comma-separated mask seeds of the PSNR comparison")
    ap.add_argument("--curve", help="comma-separated pair-id substrings: run only the fixed-focal PSNR curve")
    ap.add_argument("--curve-scales", default="0.85,0.9,0.95,1,1.05,1.1,1.2,1.35,1.5,1.65")
    args = ap.parse_args(argv)
    pairs = load_pairs([args.pairs], exclude=HELD_OUT)
    if args.curve:
        chosen = [p for p in pairs if any(k in p.id for k in args.curve.split(","))]
        if not chosen:
            ap.error(f"no pair id contains any of {args.curve!r}")
        seeds = [int(x) for x in args.psnr_seeds.split(",")]
        psnr_curve(chosen, [float(x) for x in args.curve_scales.split(",")], seeds)
        return 0
    real_pairs(pairs)
    if not args.skip_synthetic:
        synthetic(args.seeds)
    if not args.skip_psnr:
        hole_psnr(pairs, [int(x) for x in args.psnr_seeds.split(",")])
    return 0


def _threshold(px_scale: float) -> float:
    return CFG.matching.ransac_threshold_px * max(px_scale, 0.5)


def _estimates(matches, K_t, K_s, px_scale):
    """{method: (FocalEstimate, wall seconds, CPU seconds)}."""
    out = {}
    for method in METHODS:
        ic = replace(CFG.intrinsics, estimate=method)
        t0, c0 = time.perf_counter(), time.process_time()
        est = estimate_focal(matches, K_t, K_s, ic, _threshold(px_scale))
        out[method] = (est, time.perf_counter() - t0, time.process_time() - c0)
    return out


def real_pairs(pairs) -> None:
    print("== Real pairs with ground-truth K (focal error of the target image; pose errors in deg)")
    head = f"{'pair':<34s} {'f_true':>7s} {'prior':>7s}"
    head += "".join(f" {m[:8]:>9s}" for m in METHODS[1:])
    head += "".join(f" {'R/t ' + m[:6]:>13s}" for m in (*METHODS, "true K"))
    head += f" {'t_search':>8s}"
    print(head)
    errs: dict[str, list[float]] = {m: [] for m in METHODS}
    pose: dict[str, list[tuple[float, float]]] = {m: [] for m in (*METHODS, "true K")}
    times, cpu = [], []
    for pair in pairs:
        if pair.meta.get("K_target") is None:
            continue
        hole = pair_mask(pair, 0)
        target = pair.target.copy()
        target[hole] = 0
        views = prepare_views(target, hole, pair.source, CFG, None, None)
        m = match_pair(views.target, views.source, views.hole, CFG.matching, views.px_scale)
        gt_t = Intrinsics.from_matrix(np.array(pair.meta["K_target"]), *pair.target.shape[1::-1])
        gt_s = Intrinsics.from_matrix(np.array(pair.meta["K_source"]), *pair.source.shape[1::-1])
        gt_t = gt_t.resized(views.K_target.width, views.K_target.height)
        gt_s = gt_s.resized(views.K_source.width, views.K_source.height)
        est = _estimates(m, views.K_target, views.K_source, views.px_scale)
        times.append(est["search"][1])
        cpu.append(est["search"][2])
        T_gt = pair.meta.get("T_source_to_target")
        row = f"{pair.id:<34s} {gt_t.fx:7.0f} {views.K_target.fx:7.0f}"
        for method in METHODS[1:]:
            e = est[method][0]
            mark = "" if e.status == "estimated" else "*"
            row += f" {100 * (e.K_target.fx / gt_t.fx - 1):+8.1f}{mark or ' '}"
        for method in METHODS:
            errs[method].append(abs(est[method][0].K_target.fx / gt_t.fx - 1))
        for method in (*METHODS, "true K"):
            if T_gt is None:
                row += f" {'-':>13s}"
                continue
            K_t, K_s = (
                (gt_t, gt_s) if method == "true K" else (est[method][0].K_target, est[method][0].K_source)
            )
            p = estimate_pose(m, K_t, K_s, CFG.geometry, CFG.matching)
            r, t = pose_errors_deg(p.T, np.array(T_gt))
            pose[method].append((r, t))
            row += f" {r:6.2f}/{t:6.2f}"
        row += f" {est['search'][1]:8.3f}"
        print(row, flush=True)
    print("(* = prior kept: unobservable, failed or contradicted; focal error of the prior shown)")
    line = "median |focal error|: " + ", ".join(
        f"{m} {100 * statistics.median(errs[m]):.1f}%" for m in METHODS
    )
    print(line)
    for method in (*METHODS, "true K"):
        rs, ts = zip(*pose[method], strict=True)
        print(
            f"pose ({len(rs)} GT pairs) {method:<9s} median R {statistics.median(rs):.2f} deg, "
            f"t {statistics.median(ts):.2f} deg; mean R {np.mean(rs):.2f}, t {np.mean(ts):.2f}"
        )
    print(
        f"focal search time: wall median {statistics.median(times):.3f} s, max {max(times):.3f} s; "
        f"CPU median {statistics.median(cpu):.3f} s, max {max(cpu):.3f} s\n"
    )


def _synthetic_case(width, height, focal_scale, motion, baseline, seed):
    f0 = default_focal_px(width, height)
    pair = make_pair(
        seed=seed, width=width, height=height, focal_px=f0 * focal_scale, motion=motion, baseline=baseline
    )
    px_scale = max(width, height) / 1280
    m = match_pair(pair.target / 255.0, pair.source / 255.0, pair.hole, CFG.matching, px_scale)
    K0 = Intrinsics.from_focal(f0, width, height, "default", CFG.intrinsics.prior_sigma_default)
    return pair, _estimates(m, K0, K0, px_scale)


def synthetic(seeds: int) -> None:
    print("== Rendered scenes, 640x480 and 480x640, true focal 0.5x / 1x / 2x the default")
    groups = [
        ("orbit 0.5 (4.8 deg)", "orbit", 0.5, (0.5, 1.0, 2.0)),
        ("orbit 1.0 (9.5 deg)", "orbit", 1.0, (0.5, 1.0, 2.0)),
        ("sideways", "sideways", None, (0.5, 2.0)),
        ("forward", "forward", None, (0.5, 2.0)),
        ("rotate (5 deg)", "rotate", None, (0.5, 2.0)),
    ]
    print(f"{'motion':<22s} {'method':<9s} {'n':>3s} {'estimated':>9s} {'|err| med':>9s} {'max':>7s} <5%")
    for name, motion, baseline, scales in groups:
        results = {m: [] for m in METHODS[1:]}
        n_seeds = seeds if motion == "orbit" else 1
        for size in ((640, 480), (480, 640)):
            for fs in scales:
                for seed in range(n_seeds):
                    pair, est = _synthetic_case(*size, fs, motion, baseline, seed)
                    for method in METHODS[1:]:
                        e = est[method][0]
                        err = e.K_target.fx / pair.K_target[0, 0] - 1
                        results[method].append((e.status == "estimated", err))
        for method, res in results.items():
            done = [abs(err) for ok, err in res if ok]
            med = f"{100 * statistics.median(done):8.1f}%" if done else f"{'-':>9s}"
            mx = f"{100 * max(done):6.1f}%" if done else f"{'-':>7s}"
            within = sum(abs(err) < 0.05 for _, err in res)
            print(f"{name:<22s} {method:<9s} {len(res):3d} {len(done):9d} {med} {mx} {within:5d}", flush=True)
    print("(estimated: focal moved; otherwise the prior was kept and its error counts in <5%)\n")


def _final_geometry(res):
    """Working-resolution target intrinsics and pose the render used (after the optimisation)."""
    g = res.references[0].geometry
    return g.K_target, g.T


def _fill_psnr(pair, hole, cfg) -> tuple[float, object]:
    res = fill(
        pair.target, hole, pair.source, cfg, target_exif=pair.exif.target, source_exifs=[pair.exif.source]
    )
    return psnr(res.image, pair.target, hole), res


def _fixed_focal(focal_px: float | None = None) -> FillConfig:
    """The paper's setting: one focal for both images (default: 750 px at a 1280-px long side),
    EXIF ignored, nothing estimated."""
    return CFG.updated(
        {"intrinsics.estimate": "none", "intrinsics.use_exif": False, "intrinsics.focal_px": focal_px}
    )


def hole_psnr(pairs, seeds: list[int]) -> None:
    """Whole fills with the evaluation's masks: the fixed default focal, the estimate (default),
    the estimate refined by the optimisation, the true K where meta.json has it, and the fixed focal
    scaled by 0.98 / 1.02 (how much the fill moves for a 2 % focal change: the noise floor of any
    per-pair comparison)."""
    print(
        f"== Hole PSNR (geofill eval masks, seeds {','.join(map(str, seeds))}, mean over seeds): fixed "
        "focal, estimated (default), refined (optimize.refine_focal), true K; fixed focal x0.98 / x1.02"
    )
    configs = {
        "fixed": _fixed_focal(),
        "estim.": CFG,
        "refined": CFG.updated({"optimize.refine_focal": True}),
    }
    cols = (*configs, "true K", "x0.98", "x1.02")
    head = f"{'pair':<34s}" + "".join(f" {c:>7s}" for c in cols)
    print(head + f" {'est-fix':>7s} {'ref-fix':>7s} {'jitter':>6s}")
    table: dict[str, dict[str, float]] = {}
    geometry: dict[str, dict[str, tuple]] = {}
    for pair in pairs:
        cfgs = dict(configs)
        f0 = default_focal_px(*pair.target.shape[1::-1])
        if pair.meta.get("K_target") is not None:
            K_t, K_s = (np.array(pair.meta[k]) for k in ("K_target", "K_source"))
            cfgs["true K"] = CFG.updated(
                {
                    "intrinsics.target": [K_t[0, 0], K_t[1, 1], K_t[0, 2], K_t[1, 2]],
                    "intrinsics.source": [K_s[0, 0], K_s[1, 1], K_s[0, 2], K_s[1, 2]],
                }
            )
        if default_focal_px(*pair.source.shape[1::-1]) == f0:  # one focal_px fits both images
            for k in (0.98, 1.02):
                cfgs[f"x{k:.2f}"] = _fixed_focal(f0 * k)
        row: dict[str, list[float]] = {}
        for seed in seeds:
            hole = pair_mask(pair, seed)
            for name, cfg in cfgs.items():
                value, res = _fill_psnr(pair, hole, cfg)
                row.setdefault(name, []).append(value)
                if seed == seeds[0] and pair.meta.get("K_target") is not None:
                    geometry.setdefault(pair.id, {})[name] = _final_geometry(res)
        v = table[pair.id] = {k: float(np.mean(x)) for k, x in row.items()}
        line = f"{pair.id:<34s}" + "".join(f" {v[c]:7.2f}" if c in v else f" {'-':>7s}" for c in cols)
        jitter = abs(v["x1.02"] - v["x0.98"]) if "x1.02" in v else float("nan")
        line += f" {v['estim.'] - v['fixed']:+7.2f} {v['refined'] - v['fixed']:+7.2f} {jitter:6.2f}"
        worse = v["estim."] - v["fixed"] < -0.3
        print(line + ("  <-- estimate worse by > 0.3 dB" if worse else ""), flush=True)
    for c in cols:
        got = [v[c] for v in table.values() if c in v]
        print(f"{c:<8s} mean {np.mean(got):.2f} dB, median {np.median(got):.2f} dB over {len(got)} pairs")
    for c in ("estim.", "refined", "true K"):
        d = [v[c] - v["fixed"] for v in table.values() if c in v]
        print(
            f"{c:<8s} vs fixed: worse by > 0.3 dB on {sum(x < -0.3 for x in d)}/{len(d)} pairs, "
            f"better by > 0.3 dB on {sum(x > 0.3 for x in d)}"
        )
    jit = [abs(v["x1.02"] - v["x0.98"]) for v in table.values() if "x1.02" in v]
    print(
        f"|PSNR(x1.02) - PSNR(x0.98)| of the fixed focal: median {np.median(jit):.2f} dB, "
        f"max {max(jit):.2f} dB over {len(jit)} pairs"
    )

    print(
        f"\n== After the joint optimisation (seed {seeds[0]}): target focal error (%) and pose "
        "errors R/t (deg) of the geometry the render used"
    )
    names = ("fixed", "estim.", "refined", "true K")
    print(f"{'pair':<34s}" + "".join(f" {n:>21s}" for n in names))
    errs: dict[str, list[tuple[float, float, float]]] = {n: [] for n in names}
    for pair in pairs:
        if pair.id not in geometry:
            continue
        K_gt = Intrinsics.from_matrix(np.array(pair.meta["K_target"]), *pair.target.shape[1::-1])
        T_gt = pair.meta.get("T_source_to_target")
        line = f"{pair.id:<34s}"
        for n in names:
            K, T = geometry[pair.id][n]
            fe = 100 * (K.fx / K_gt.resized(K.width, K.height).fx - 1)
            r, t = pose_errors_deg(T, np.array(T_gt)) if T_gt is not None else (float("nan"), float("nan"))
            if T_gt is not None:
                errs[n].append((abs(fe), r, t))
            line += f" {fe:+6.1f}% {r:5.2f}/{t:6.2f}"
        print(line, flush=True)
    for n in names:
        f, r, t = zip(*errs[n], strict=True)
        print(
            f"{n:<8s} ({len(r)} GT-pose pairs) median |focal err| {np.median(f):.1f}%, "
            f"R {np.median(r):.2f} deg, t {np.median(t):.2f} deg; mean R {np.mean(r):.2f}, t {np.mean(t):.2f}"
        )


def _default_scale(K: Intrinsics) -> float:
    return K.fx / default_focal_px(K.width, K.height)


def psnr_curve(pairs, scales: list[float], seeds: list[int]) -> None:
    print(
        f"== Hole PSNR (dB) of the fixed focal = scale x default, mask seeds {','.join(map(str, seeds))}; "
        "'estim.' rows: the default pipeline (focal estimated), at the scale it chose"
    )
    for pair in pairs:
        f0 = default_focal_px(*pair.target.shape[1::-1])
        truth = ""
        if pair.meta.get("K_target") is not None:
            truth = f", true focal x{pair.meta['K_target'][0][0] / f0:.3f}"
        print(f"-- {pair.id} (default focal {f0:.0f} px{truth})")
        print(f"{'scale':>8s}" + "".join(f" {'seed ' + str(s):>8s}" for s in seeds) + f" {'mean':>7s}")
        holes = [pair_mask(pair, seed) for seed in seeds]
        means = []
        for k in scales:
            v = [_fill_psnr(pair, hole, _fixed_focal(f0 * k))[0] for hole in holes]
            means.append(float(np.mean(v)))
            print(f"x{k:<7.3f}" + "".join(f" {x:8.2f}" for x in v) + f" {means[-1]:7.2f}", flush=True)
        est = [_fill_psnr(pair, hole, CFG) for hole in holes]
        chosen = " ".join(f"x{_default_scale(r.references[0].focal.K_target):.3f}" for _, r in est)
        v = [x for x, _ in est]
        print(f"{'estim.':<8s}" + "".join(f" {x:8.2f}" for x in v) + f" {np.mean(v):7.2f}  (scales {chosen})")
        steps = np.abs(np.diff(means))
        best = scales[int(np.argmax(means))]
        print(
            f"mean over seeds: range {min(means):.2f}..{max(means):.2f} dB, best at x{best:.3f}; "
            f"|change| between neighbouring scales median {np.median(steps):.2f}, max {steps.max():.2f} dB",
            flush=True,
        )


if __name__ == "__main__":
    sys.exit(main())
