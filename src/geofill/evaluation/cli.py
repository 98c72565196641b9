"""``geofill eval``: the command-line face of :mod:`geofill.evaluation.runner`.

Mount it as a subcommand with :func:`add_arguments` + :func:`run`, or call :func:`main_eval`."""

from __future__ import annotations

import argparse
import sys

from ..config import FillConfig, parse_overrides
from ..errors import GeoFillError
from .masks import DEFAULT_AREA_RANGE, DEFAULT_STROKE_WIDTH_720P
from .methods import DEFAULT_METHODS, METHODS, register_geofill_methods, resolve_methods
from .pairs import load_pairs
from .removal import PROTOCOLS, REMOVAL_MASKS
from .runner import REFERENCE_MODES, run_eval, sweep


def _area_range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected LO,HI (e.g. 0.1,0.3), got {text!r}") from exc
    if not 0.0 < lo <= hi < 1.0:
        raise argparse.ArgumentTypeError(f"need 0 < LO <= HI < 1, got {text!r}")
    return lo, hi


def _reference_modes(text: str) -> tuple[str, ...]:
    modes = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in modes if m not in REFERENCE_MODES]
    if bad or not modes:
        raise argparse.ArgumentTypeError(f"expected a comma-separated subset of {','.join(REFERENCE_MODES)}")
    return modes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``geofill eval`` flags."""
    parser.add_argument(
        "--pairs",
        action="append",
        required=True,
        metavar="DIR",
        help="a pair folder, a folder of pair folders, synthetic:N (rendered pairs) or synthetic-views:N "
        "(rendered sets with two references) (repeatable)",
    )
    parser.add_argument(
        "--exclude",
        action="append",
        default=[],
        metavar="NAME",
        help="leave the pair folder NAME out of a folder of pair folders, unread (repeatable)",
    )
    parser.add_argument("--out", required=True, metavar="OUTDIR", help="folder for the results")
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="mask seed (and removal protocols' cases), combined with each pair id (default 0)",
    )
    parser.add_argument(
        "--methods",
        metavar="A,B",
        help=f"comma-separated methods (default: {','.join(DEFAULT_METHODS)}; "
        f"registered: {', '.join(METHODS)})",
    )
    parser.add_argument(
        "--stroke-width",
        type=float,
        metavar="PX",
        help=f"mean brush width (px at a 720-px short side, scaled; default {DEFAULT_STROKE_WIDTH_720P:g})",
    )
    parser.add_argument(
        "--area-range",
        type=_area_range,
        default=DEFAULT_AREA_RANGE,
        metavar="LO,HI",
        help="hole area as a fraction of the image (default {:g},{:g})".format(*DEFAULT_AREA_RANGE),
    )
    parser.add_argument(
        "--sweep",
        choices=["hole-size"],
        help="hole-size study: the same holes at mean brush widths 90..210 px (720p)",
    )
    parser.add_argument("--config", metavar="FILE", help="base FillConfig JSON for the geofill methods")
    parser.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a geofill config key (repeatable)"
    )
    parser.add_argument("--by", metavar="FIELD", help="group the summary by a meta.json field (e.g. kind)")
    parser.add_argument("--limit", type=int, metavar="N", help="first N pairs only (by id)")
    parser.add_argument(
        "--references",
        type=_reference_modes,
        default=REFERENCE_MODES,
        metavar="MODES",
        help="on multi-reference sets (source2.*, ...), run each method with: primary (the primary "
        "reference alone, always), each (every other reference alone, as '<method>[ref k]'), all "
        "(every reference at once, as '<method>[all]', for methods that take several); "
        f"comma-separated (default: {','.join(REFERENCE_MODES)})",
    )
    parser.add_argument(
        "--protocol",
        choices=PROTOCOLS,
        default="restoration",
        help="restoration (default): a brush-stroke hole cut into the background and blanked; "
        "static: a planar photo cutout placed in front of the scene and drawn into the target and every "
        "reference with the GT-pose projection (sets with K and poses, synthetic:N); solid / "
        "solid_plain: a box (photo faces / one colour, shaded) placed in 3D and ray-cast into every "
        "view; walker / walker_crowd: a person-shaped cutout standing elsewhere in each reference "
        "(crowd: and passers-by in the references); strangers: the brush-stroke hole shows a cutout "
        "and other cutouts cover 30-60 %% of the hole's background in the references. The removal "
        "protocols give the methods the target showing the object, score against the clean target "
        "and add the leak (the object reproduced in place) and the ghost (an object reproduced "
        "anywhere in the hole)",
    )
    parser.add_argument(
        "--removal-mask",
        choices=REMOVAL_MASKS,
        default=REMOVAL_MASKS[0],
        help="the removal protocols' hole: brushed (default): the object's silhouette closed and "
        "dilated by a wobbly 15-45 px margin at a 1280-px long side, as people brush; tight: the "
        "silhouette dilated by 4 px at 720p (strangers: the cutout fills the stroke hole)",
    )
    parser.add_argument(
        "--lpips-model",
        metavar="FILE",
        help="local TorchScript/ONNX LPIPS model (default: $GEOFILL_LPIPS_MODEL)",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``geofill eval`` with parsed ``args``; the exit code."""
    if args.removal_mask != REMOVAL_MASKS[0] and args.protocol == "restoration":
        print("geofill eval: --removal-mask needs a removal --protocol", file=sys.stderr)
        return 2
    if args.sweep and args.protocol != "restoration":
        print("geofill eval: --sweep runs the restoration protocol only; drop --protocol", file=sys.stderr)
        return 2
    if args.sweep and (args.stroke_width is not None or args.by):
        print(
            "geofill eval: --sweep sets its own stroke widths and does not group; drop --stroke-width/--by",
            file=sys.stderr,
        )
        return 2
    try:
        base = FillConfig.from_json(args.config) if args.config else FillConfig()
        register_geofill_methods(base.updated(parse_overrides(args.set)))
        methods = resolve_methods([m.strip() for m in args.methods.split(",")] if args.methods else None)
        pairs = load_pairs(args.pairs, exclude=args.exclude)
        if args.limit is not None:
            pairs = pairs[: max(0, args.limit)]
        if args.sweep == "hole-size":
            sweep(
                pairs,
                methods,
                args.out,
                args.seed,
                area_range=args.area_range,
                lpips_model=args.lpips_model,
            )
            print(f"hole-size sweep written to {args.out}/sweep.md", file=sys.stderr)
        else:
            run_eval(
                pairs,
                methods,
                args.out,
                args.seed,
                args.stroke_width,
                args.by,
                area_range=args.area_range,
                lpips_model=args.lpips_model,
                references=args.references,
                protocol=args.protocol,
                removal_mask=args.removal_mask,
            )
            print(f"summary written to {args.out}/summary.md", file=sys.stderr)
    except GeoFillError as exc:
        print(f"geofill eval: {exc}", file=sys.stderr)
        return exc.exit_code
    return 0


def main_eval(argv: list[str] | None = None) -> int:
    """``geofill eval`` entry point."""
    parser = argparse.ArgumentParser(
        prog="geofill eval",
        description="Cut brush-stroke holes into evaluation pairs (or draw objects to remove into "
        "them: --protocol), fill them with each method, score them.",
    )
    add_arguments(parser)
    return run(parser.parse_args(argv))
