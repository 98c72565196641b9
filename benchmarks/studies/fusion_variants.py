"""Fuse-stage variants on the same per-reference renders: every multi-reference set's references
run once up to ``refine`` (all references, as ``geofill eval``'s ``geofill[all]`` runs them), then
the screen, fuse and composite stages per variant, scored like ``geofill eval`` (hole PSNR; leak in
the removal protocols).

    .venv/bin/python benchmarks/studies/fusion_variants.py --protocol strangers \\
        --variant "" --variant "fusion.cross_strangers=off" [--cache DIR] [--pairs DIR]

``--oracle`` also prints, per set, on the hole pixels the fused render covers: the fused render's
PSNR, and the renders chosen knowing the truth per pixel and per 24-px box (the box's mean error).

A variant is comma-separated ``--set`` items (empty: the defaults); the screen stage runs per
variant (with its settings), the stages before it once with the defaults or the ``--render-set``
items (which every variant then includes). ``--cache`` keeps the
renders (pickles) between runs. Prints one line per variant: mean hole PSNR, mean leak, median fuse
time, then each set's figures.
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, MULTIVIEW


def _cases(pairs: list[str], protocol: str, seed: int):
    """(set id, pair as given to the method, target as given, hole, truth, leak objects or None)."""
    from geofill.evaluation.pairs import load_pairs, pair_mask
    from geofill.evaluation.removal import ProtocolSkip, make_case
    from geofill.synthetic import blanked

    for pair in load_pairs(pairs, exclude=HELD_OUT):
        if len(pair.sources) < 2:
            continue
        if protocol == "restoration":
            hole = pair_mask(pair, seed)
            yield pair.id, pair, blanked(pair.target, hole), hole, pair.target, None
            continue
        try:
            case = make_case(protocol, pair, seed)
        except ProtocolSkip as exc:
            print(f"{pair.id}: skipped: {exc}", file=sys.stderr)
            continue
        yield pair.id, case.pair, case.pair.target, case.hole, case.truth, case.objects


def _renders(
    pairs: list[str], protocol: str, cache: Path | None, seed: int = 0, settings: Sequence[str] = ()
) -> list[tuple]:
    """Per set: (id, context, references up to the refine stage, hole, truth, objects), the
    references through the same stages as :func:`geofill.pipeline.fill` runs them, under the
    ``settings`` (``key=value`` items; the defaults where empty)."""
    from geofill.config import FillConfig, parse_overrides
    from geofill.io import as_rgb_uint8
    from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_all_references
    from geofill.progress import Progress

    cfg = FillConfig().updated(parse_overrides(list(settings))) if settings else FillConfig()
    # Keyed by the whole configuration, so that renders cached under other defaults are not reused.
    tag = hashlib.sha256(repr(cfg).encode()).hexdigest()[:12]
    out = []
    for set_id, pair, shown, hole, truth, objects in _cases(pairs, protocol, seed):
        path = cache / f"{protocol}_{seed}_{tag}_{set_id}.pkl" if cache else None
        if path is not None and path.is_file():
            ctx, refs = pickle.loads(path.read_bytes())
            ctx = replace(ctx, inpainter=prepare_fill(shown, hole, pair.sources, cfg).inpainter)
        else:
            t0 = time.perf_counter()
            ctx = prepare_fill(shown, hole, pair.sources, cfg, pair.exif.target)
            refs = [
                ReferenceArtifacts(i + 1, as_rgb_uint8(s), e)
                for i, (s, e) in enumerate(zip(pair.sources, pair.exif.sources, strict=True))
            ]
            refs, _ = run_all_references(ctx, refs, Progress(quiet=True), until="refine")
            print(f"{set_id}: renders in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
                part = path.with_suffix(".part")  # renamed when whole: a full disk leaves no torn pickle
                part.write_bytes(pickle.dumps((replace(ctx, inpainter=None), refs)))
                part.replace(path)
        out.append((set_id, ctx, refs, hole, truth, objects))
    return out


def screened(ctx, refs: list, cfg) -> list:
    """The references through the screen stage under ``cfg``."""
    from geofill.pipeline import _run_references
    from geofill.progress import Progress

    return _run_references(replace(ctx, cfg=cfg), refs, Progress(quiet=True))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--protocol", default="restoration", choices=("restoration", "static", "strangers"))
    ap.add_argument("--pairs", action="append", default=None, help=f"as geofill eval's (default {MULTIVIEW})")
    ap.add_argument("--seed", type=int, default=0, help="mask and protocol seed, as geofill eval's")
    ap.add_argument("--variant", action="append", default=None, help="comma-separated key=value (repeatable)")
    ap.add_argument(
        "--render-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a setting for the stages before the screen (repeatable; e.g. registration.joint=auto)",
    )
    ap.add_argument("--cache", type=Path, help="folder keeping the renders between runs")
    ap.add_argument("--oracle", action="store_true", help="also the choices made knowing the truth")
    args = ap.parse_args(argv)

    from geofill.config import FillConfig, parse_overrides
    from geofill.evaluation.metrics import leak, psnr
    from geofill.fuse import fuse_references
    from geofill.pipeline import composite

    sets = _renders(args.pairs or [str(MULTIVIEW)], args.protocol, args.cache, args.seed, args.render_set)
    for variant in args.variant or [""]:
        items = args.render_set + [v for v in variant.split(",") if v]
        cfg = FillConfig().updated(parse_overrides(items)) if items else FillConfig()
        scores, leaks, times, cells = [], [], [], []
        for set_id, ctx, refs, hole, truth, objects in sets:
            refs = screened(ctx, refs, cfg)
            t0 = time.perf_counter()
            fusion = fuse_references(ctx.target, ctx.hole, [r for r in refs if r.usable], cfg)
            times.append(time.perf_counter() - t0)
            image = np.where(hole[..., None], composite(replace(ctx, cfg=cfg), fusion), truth)
            scores.append(psnr(image, truth, hole))
            cell = f"{set_id.removeprefix('dev_mv_')} {scores[-1]:.2f}"
            if objects:
                leaks.append(leak(image, truth, objects, hole).fraction or 0.0)
                cell += f"/{leaks[-1]:.3f}"
            cells.append(cell)
        head = f"{np.mean(scores):.3f} dB" + (f" leak {np.mean(leaks):.3f}" if leaks else "")
        print(f"[{variant or 'defaults'}] {head}, fuse {np.median(times):.2f} s | " + ", ".join(cells))
    if args.oracle:
        for set_id, ctx, refs, hole, truth, _ in sets:
            _oracle(set_id, ctx, [r for r in screened(ctx, refs, ctx.cfg) if r.usable], hole, truth)
    return 0


def _oracle(set_id: str, ctx, refs: list, hole: np.ndarray, truth: np.ndarray) -> None:
    """The fused render against the renders chosen knowing the truth, per pixel and per 24-px box,
    on the hole pixels the fused render covers."""
    import cv2

    from geofill.evaluation.metrics import psnr
    from geofill.fuse import fuse_references

    fusion = fuse_references(ctx.target, hole, refs, ctx.cfg)
    region = hole & fusion.alpha
    images = np.stack([r.screened.image for r in refs])
    errors = np.stack(
        [
            np.where(r.screened.alpha, np.abs(r.screened.image.astype(np.float32) - truth).mean(axis=2), 1e3)
            for r in refs
        ]
    )
    boxed = np.stack([cv2.blur(e, (24, 24)) for e in errors])

    def chosen(err: np.ndarray) -> float:
        pick = np.take_along_axis(images, err.argmin(axis=0)[None, ..., None], 0)[0]
        return psnr(np.where(region[..., None], pick, truth), truth, region)

    fused = psnr(np.where(region[..., None], fusion.image, truth), truth, region)
    print(
        f"{set_id}: fused {fused:.2f}, per-pixel oracle {chosen(errors):.2f}, "
        f"24-px box oracle {chosen(boxed):.2f}"
    )


if __name__ == "__main__":
    sys.exit(main())
