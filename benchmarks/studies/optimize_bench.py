"""Joint pose-depth optimisation: both solvers from the same start, on synthetic scenes with
a perturbed start and on the real pairs. Figures, not a test.

    .venv/bin/python benchmarks/studies/optimize_bench.py synthetic [--scenes 3] [--size 1280x720]
    .venv/bin/python benchmarks/studies/optimize_bench.py real [--pairs ../shared/data/pairs] [--only a,b]
    .venv/bin/python benchmarks/studies/optimize_bench.py focal [--scenes 3] [--ratios 0.8,1.25]
    .venv/bin/python benchmarks/studies/optimize_bench.py eval -- <geofill eval arguments>

``synthetic``: exact depth and pose of :func:`geofill.synthetic.make_pair`, then the start is
perturbed (rotation by ``--rot`` deg about a random axis, translation direction by ``--tdir`` deg,
depth scaled by 1 + ``--scale``); SIFT matches and pose inliers come from the pipeline. Prints the
final rotation / translation-direction / depth-scale errors, the objective and the wall time of each
solver. ``real``: the pipeline's own start (pose, sparse depth) on each pair with the evaluation's
brush hole (seed 0); prints the objective of both solvers and, where meta.json has a GT pose, the
rotation and translation-direction errors before and after. ``focal``: synthetic pairs
whose true focal is ``--ratios`` times the assumed default, filled with and without
``optimize.refine_focal``; prints the focal, the pose errors and the hole PSNR. ``eval``: ``geofill
eval`` with the depth stage's result cached per pair, so that every method starts from the same
depth: the sparse backend (OpenCV's EdgeAwareInterpolator) does not return the same map twice for
the same input, which would add its noise to the differences between optimisation variants.
``--starts DIR`` keeps each real pair's start so that separate runs compare the same one.
``--paper-scale`` multiplies the paper solver's iteration limits (1 = the paper's
4000/7000/9000/10000); ``--solvers`` picks the solvers.
"""

from __future__ import annotations

import argparse
import pickle
import statistics
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import pytorch_optimizer  # noqa: F401  (imported here, not inside the first timed paper run)
from scipy.spatial.transform import Rotation

from geofill.camera import Intrinsics, default_focal_px, pose_errors_deg
from geofill.config import FillConfig, parse_overrides
from geofill.depth.align import AlignedDepth
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.optimize import OptimizationResult, optimize_pose_depth
from geofill.pipeline import ReferenceArtifacts, fill, prepare_fill, run_reference
from geofill.synthetic import make_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS


@dataclass
class Start:
    """Everything one optimisation run needs (working resolution)."""

    art: ReferenceArtifacts  # stopped after the depth stage
    T: np.ndarray
    depth: AlignedDepth


def pipeline_start(target, hole, source, cfg: FillConfig) -> Start | None:
    """The pipeline's own start: its stages up to the depth, where the optimisation takes over."""
    ctx = prepare_fill(target, hole, [source], cfg)
    art = run_reference(ctx, ReferenceArtifacts(1, source), until="depth")
    if art.dropped or art.pose.status != "ok":
        return None
    return Start(art, art.pose.T, art.depth.aligned)


def cached_start(pair, cfg: FillConfig, folder: str | None) -> Start | None:
    """The pipeline start of ``pair`` (brush hole seed 0), kept as a pickle in ``folder`` when given:
    the sparse depth backend does not return the same map twice, so runs that must compare solvers
    across processes (e.g. a long paper-solver run and a later fast-solver one) share the file."""
    path = Path(folder) / f"{pair.id}.pkl" if folder else None
    if path is not None and path.is_file():
        return pickle.loads(path.read_bytes())
    start = pipeline_start(pair.target, pair_mask(pair, 0), pair.source, cfg)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(pickle.dumps(start))
    return start


def run(
    start: Start, cfg: FillConfig, solver: str, paper_scale: float
) -> tuple[OptimizationResult, float, float]:
    """One solver from ``start``: the result, its wall time and its CPU time (s). The optimisation is
    single-threaded (``optimize.threads``), so on a machine shared with other jobs its CPU time is
    what the wall time would be on a quiet one."""
    oc = replace(cfg.optimize, solver=solver)
    if solver == "paper":
        oc = replace(oc, paper_iterations=[max(1, round(n * paper_scale)) for n in oc.paper_iterations])
    v, m, inl, K = start.art.views, start.art.matches, start.art.pose.inliers, start.art.focal
    t0, c0 = time.perf_counter(), time.process_time()
    res = optimize_pose_depth(
        v.target, v.hole, v.source, K.K_target, K.K_source, start.T, start.depth,
        m.pts_target[inl], m.pts_source[inl], oc,
    )  # fmt: skip
    return res, time.perf_counter() - t0, time.process_time() - c0


def perturb(T: np.ndarray, rot_deg: float, tdir_deg: float, rng: np.random.Generator) -> np.ndarray:
    """``T`` with its rotation turned by ``rot_deg`` about a random axis and its translation direction
    by ``tdir_deg`` about a random axis orthogonal to it."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    t = T[:3, 3]
    ortho = np.cross(t, rng.normal(size=3))
    ortho /= np.linalg.norm(ortho)
    out = T.copy()
    out[:3, :3] = Rotation.from_rotvec(np.radians(rot_deg) * axis).as_matrix() @ T[:3, :3]
    out[:3, 3] = Rotation.from_rotvec(np.radians(tdir_deg) * ortho).as_matrix() @ t
    return out


def synthetic(args, cfg: FillConfig) -> None:
    w, h = (int(x) for x in args.size.split("x"))
    print(
        f"synthetic {w}x{h}, start: rotation {args.rot} deg, translation direction {args.tdir} deg, "
        f"depth x{1 + args.scale:g}; paper iterations x{args.paper_scale:g}"
    )
    cols = ("R_err", "t_err", "s_err%", "objective", "status", "wall_s", "cpu_s")
    print(f"{'scene':<8s} {'solver':<6s} " + " ".join(f"{c:>13s}" for c in cols))
    rows: dict[str, list] = {s: [] for s in args.solvers}
    for seed in range(args.scenes):
        sp = make_pair(seed=seed, width=w, height=h)
        # The scene's focal is the default one: keep it (no estimation), so only the optimiser moves.
        start = pipeline_start(sp.target, sp.hole, sp.source, cfg.updated({"intrinsics.estimate": "none"}))
        if start is None:
            print(f"seed {seed}: the pipeline found no usable pose; skipped")
            continue
        T_gt = sp.T_source_to_target.copy()
        baseline = np.linalg.norm(T_gt[:3, 3])
        T_gt[:3, 3] /= baseline
        v = start.art.focal
        K_s = Intrinsics.from_matrix(sp.K_source, w, h).resized(v.K_source.width, v.K_source.height)
        assert np.isclose(K_s.fx, v.K_source.fx), "benchmark assumes the default focal is the true one"
        z = sp.depth_source / baseline
        z = cv2.resize(z, (v.K_source.width, v.K_source.height), interpolation=cv2.INTER_NEAREST)
        depth = AlignedDepth(
            (z * (1 + args.scale)).astype(np.float32), 1.0, 0.0, "inverse", "gt", 0, 0.0, 0.0
        )
        T0 = perturb(T_gt, args.rot, args.tdir, np.random.default_rng(seed))
        start = Start(start.art, T0, depth)
        r0, t0 = pose_errors_deg(T0, T_gt)
        print(f"{seed:<8d} {'start':<6s} {r0:13.3f} {t0:13.3f} {100 * args.scale:13.2f}")
        for solver in args.solvers:
            res, wall, cpu = run(start, cfg, solver, args.paper_scale)
            r, t = pose_errors_deg(res.T, T_gt)
            s_err = 100 * abs(res.params.scale / (1 + args.scale) - 1)
            rep = res.report
            rows[solver].append((r, t, s_err, rep.final_objective, wall, cpu))
            print(
                f"{seed:<8d} {solver:<6s} {r:13.3f} {t:13.3f} {s_err:13.2f} {rep.final_objective:13.7e} "
                f"{rep.status:>13s} {wall:13.2f} {cpu:13.2f}",
                flush=True,
            )
    for solver, rs in rows.items():
        if rs:
            m = [statistics.median(c) for c in zip(*rs, strict=True)]
            print(
                f"{'MEDIAN':<8s} {solver:<6s} {m[0]:13.3f} {m[1]:13.3f} {m[2]:13.2f} {m[3]:13.7e} "
                f"{'':>13s} {m[4]:13.2f} {m[5]:13.2f}"
            )


def real(args, cfg: FillConfig) -> None:
    pairs = load_pairs([args.pairs], exclude=HELD_OUT)
    if args.only:
        pairs = [p for p in pairs if p.id in args.only.split(",")]
    print(f"real pairs, pipeline start, brush hole seed 0; paper iterations x{args.paper_scale:g}")
    cols = ["R0", "t0"] + [f"{c}_{s}" for s in args.solvers for c in ("R", "t", "obj", "wall", "cpu")]
    print(f"{'pair':<34s} {'obj0':>12s} " + " ".join(f"{c:>12s}" for c in cols))
    gt_rows = []
    for pair in pairs:
        start = cached_start(pair, cfg, args.starts)
        if start is None:
            print(f"{pair.id:<34s} no usable pose (skipped)")
            continue
        T_gt = pair.meta.get("T_source_to_target")
        gt = None if T_gt is None else np.array(T_gt)
        row = dict(zip(("R0", "t0"), _errors(start.T, gt), strict=True))
        obj0, flags = np.nan, []
        for solver in args.solvers:
            res, wall, cpu = run(start, cfg, solver, args.paper_scale)
            obj0 = res.report.initial_objective
            row |= dict(zip((f"R_{solver}", f"t_{solver}"), _errors(res.T, gt), strict=True))
            rep = res.report  # the objective of the geometry returned (the start's when rejected)
            obj = rep.final_objective if rep.status == "accepted" else rep.initial_objective
            row |= {f"obj_{solver}": obj, f"wall_{solver}": wall, f"cpu_{solver}": cpu}
            flags.append(f"{solver} {rep.status}" if rep.status != "accepted" else "")
        note = "; ".join(f for f in flags if f)
        print(
            f"{pair.id:<34s} {obj0:12.6e} " + " ".join(_fmt(row[c]) for c in cols) + f"  {note}", flush=True
        )
        if T_gt is not None:
            gt_rows.append(row)
    for name, fn in (("MEAN (GT)", statistics.mean), ("MEDIAN (GT)", statistics.median)):
        if gt_rows:
            print(f"{name:<34s} {'':>12s} " + " ".join(_fmt(fn([r[c] for r in gt_rows])) for c in cols))


def focal(args, cfg: FillConfig) -> None:
    w, h = (int(x) for x in args.size.split("x"))
    f0 = default_focal_px(w, h)
    print(f"focal refinement, synthetic {w}x{h}, assumed focal {f0:g} px (the default)")
    cols = ("ratio", "refine", "f_true", "f_used", "R_err", "t_err", "psnr_hole")
    print(f"{'scene':<6s} " + " ".join(f"{c:>9s}" for c in cols))
    for ratio in args.ratios:
        for seed in range(args.scenes):
            sp = make_pair(seed=seed, width=w, height=h, focal_px=f0 * ratio)
            for refine in (False, True):
                res = fill(sp.target, sp.hole, sp.source, cfg.updated({"optimize.refine_focal": refine}))
                o = res.references[0].geometry.result
                if o is None:
                    print(f"{seed:<6d} {ratio:9.2f} {refine!s:>9s} no optimisation ({res.report.status})")
                    continue
                r, t = pose_errors_deg(o.T, sp.T_source_to_target)
                p = psnr(res.image, sp.target, sp.hole)
                vals = (f0 * ratio, o.K_target.fx, r, t, p)
                print(
                    f"{seed:<6d} {ratio:9.2f} {refine!s:>9s} " + " ".join(f"{v:9.3f}" for v in vals),
                    flush=True,
                )


def eval_same_depth(argv: list[str]) -> int:
    """``geofill eval`` with the depth stage (:func:`geofill.pipeline.source_depth`) memoised per
    (source, hole, pose, backend) content, so every variant renders the same depth."""
    import hashlib

    import geofill.pipeline as pipeline
    from geofill.evaluation.cli import main_eval

    compute, cache = pipeline.source_depth, {}

    def cached(views, focal, pose, points, choice, source_shape, cfg):
        h = hashlib.sha1()
        for a in (views.source, views.hole, pose.T, points.xyz_source):
            h.update(np.ascontiguousarray(a).tobytes())
        key = (h.hexdigest(), choice.name)
        if key not in cache:
            cache[key] = compute(views, focal, pose, points, choice, source_shape, cfg)
        return cache[key]

    pipeline.source_depth = cached
    return main_eval(argv)


def _errors(T: np.ndarray, T_gt: np.ndarray | None) -> tuple[float, float]:
    return (np.nan, np.nan) if T_gt is None else pose_errors_deg(T, T_gt)


def _fmt(v: float) -> str:
    return f"{v:12.6e}" if abs(v) < 1e-3 and v != 0 else f"{v:12.3f}"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["eval"]:
        return eval_same_depth([a for a in argv[1:] if a != "--"])
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["synthetic", "real", "focal"])
    ap.add_argument("--solvers", default="fast,paper", type=lambda s: s.split(","))
    ap.add_argument("--paper-scale", type=float, default=1.0, help="multiplies the paper iteration limits")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--rot", type=float, default=5.0)
    ap.add_argument("--tdir", type=float, default=10.0)
    ap.add_argument("--scale", type=float, default=0.2)
    ap.add_argument("--ratios", default="0.8,1.25", type=lambda s: [float(x) for x in s.split(",")])
    ap.add_argument("--pairs", default=str(PAIRS))
    ap.add_argument("--only", help="comma-separated pair ids")
    ap.add_argument("--starts", metavar="DIR", help="real: keep/reuse each pair's start as a pickle here")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override (repeatable)")
    args = ap.parse_args(argv)
    cfg = FillConfig().updated(parse_overrides(args.set))
    {"synthetic": synthetic, "real": real, "focal": focal}[args.mode](args, cfg)
    return 0


if __name__ == "__main__":
    sys.exit(main())
