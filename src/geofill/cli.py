"""Command line: ``geofill fill``, ``geofill demo``, ``geofill eval``, ``geofill serve``, ``geofill config``.

Every user-facing problem is one line on stderr and a non-zero exit status, with nothing written."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .config import FillConfig, parse_overrides
from .errors import GeoFillError
from .progress import Progress


def _config_from_args(args: argparse.Namespace) -> FillConfig:
    cfg = FillConfig.from_json(args.config) if args.config else FillConfig()
    overrides = parse_overrides(args.set)
    flag_map = {
        "depth": "depth.backend",
        "depth_file": "depth.file_path",
        "depth_kind": "depth.file_kind",
        "depth_scale": "depth.file_scale",
        "depth_model": "depth.model_path",
        "focal": "intrinsics.focal_px",
        "target_intrinsics": "intrinsics.target",
        "source_intrinsics": "intrinsics.source",
        "working_max_side": "working_max_side",
        "max_pixels": "max_pixels",
    }
    for attr, key in flag_map.items():
        value = getattr(args, attr, None)
        if value is not None:
            overrides[key] = value
    if getattr(args, "depth_metric", False):
        overrides["depth.file_metric"] = True
    if getattr(args, "no_exif", False):
        overrides["intrinsics.use_exif"] = False
    if getattr(args, "depth_file", None) and getattr(args, "depth", None) is None:
        overrides["depth.backend"] = "file"
    return cfg.updated(overrides) if overrides else cfg


def _floats4(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"expected FX,FY,CX,CY (4 numbers), got {text!r}")
    return values


def _add_config_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="JSON config file (see `geofill config`)")
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config key, e.g. depth.backend=file"
    )
    p.add_argument(
        "--depth",
        choices=["auto", "stereo", "fused", "onnx", "sparse", "file"],
        help="depth backend (default: auto = fused when learned-depth weights resolve, else stereo)",
    )
    p.add_argument(
        "--depth-model", metavar="PATH", help="ONNX file of the learned depth model (depth.model) to use"
    )
    p.add_argument("--depth-file", help="depth/disparity map of the SOURCE (.npy, 16-bit PNG, TIFF, EXR)")
    p.add_argument(
        "--depth-kind", choices=["depth", "inverse_depth", "disparity"], help="what --depth-file holds"
    )
    p.add_argument(
        "--depth-scale", type=float, help="multiply --depth-file values by this (e.g. 0.001 for mm)"
    )
    p.add_argument(
        "--depth-metric", action="store_true", help="--depth-file is metric depth: fit a scale only"
    )
    p.add_argument("--focal", type=float, metavar="PX", help="focal length in px of the input images (both)")
    p.add_argument(
        "--target-intrinsics", type=_floats4, metavar="FX,FY,CX,CY", help="calibrated target camera (px)"
    )
    p.add_argument(
        "--source-intrinsics", type=_floats4, metavar="FX,FY,CX,CY", help="calibrated source camera (px)"
    )
    p.add_argument("--no-exif", action="store_true", help="ignore EXIF focal lengths")
    p.add_argument("--working-max-side", type=int, metavar="PX", help="long side for geometry (default 1280)")
    p.add_argument("--max-pixels", type=int, help="refuse images with more pixels than this")


def cmd_fill(args: argparse.Namespace) -> int:
    from .debug import write_debug
    from .io import check_output_path, read_image, read_mask, validate_pair, write_image_atomic
    from .pipeline import fill

    cfg = _config_from_args(args)
    check_output_path(args.output)
    target = read_image(args.target, max_pixels=cfg.max_pixels, min_side=cfg.min_side_px)
    source = read_image(args.source, max_pixels=cfg.max_pixels, min_side=cfg.min_side_px)
    mask = read_mask(args.mask, max_pixels=cfg.max_pixels)
    # Validated here too so that errors name the files rather than "target"/"mask".
    validate_pair(
        target.pixels,
        mask,
        source.pixels,
        min_side=cfg.min_side_px,
        max_pixels=cfg.max_pixels,
        max_mask_fraction=cfg.max_mask_fraction,
        names=(args.target, args.mask, args.source),
    )
    prog = Progress(quiet=args.quiet)
    result = fill(
        target.pixels,
        mask,
        source.pixels,
        cfg,
        target_exif=target.exif,
        source_exif=source.exif,
        progress=prog,
    )
    if args.debug_dir:
        write_debug(args.debug_dir, result, mask, cfg)
    write_image_atomic(args.output, result.image)
    r = result.report
    how = "from the source" if r.status == "reference" else "by single-image inpainting"
    prog.say(
        f"wrote {args.output}: hole of {r.hole_pixels} px filled {how} in {sum(r.timings_s.values()):.2f} s"
    )
    return 0


def cmd_config(args: argparse.Namespace) -> int:
    print(_config_from_args(args).to_json())
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    run_demo(Path(args.out), seed=args.seed, quiet=args.quiet)
    return 0


def cmd_serve(args: argparse.Namespace) -> int:
    try:
        import uvicorn

        from .server.app import create_app
        from .server.jobs import ServerSettings
    except ImportError as exc:
        raise GeoFillError(
            f'geofill serve needs the server extra: pip install "geofill[server]" ({exc})'
        ) from exc

    cfg = FillConfig.from_json(args.config) if args.config else FillConfig()
    overrides = parse_overrides(args.set)
    cfg = cfg.updated(overrides) if overrides else cfg
    defaults = ServerSettings()
    settings = ServerSettings(
        workers=args.workers or defaults.workers,
        queue_size=args.queue,
        job_ttl_s=args.job_ttl,
        max_upload_bytes=int(args.max_upload_mb * 1024 * 1024),
        max_request_bytes=int(args.max_upload_mb * 1024 * 1024) * (args.max_sources + 2),
        max_pixels=args.max_pixels,
        max_sources=args.max_sources,
    )
    url = f"http://{args.host}:{args.port}/"
    print(f"geofill: serving on {url} ({settings.workers} worker(s); Ctrl+C to stop)", file=sys.stderr)
    if args.open:
        import threading
        import webbrowser

        threading.Timer(1.5, webbrowser.open, (url,)).start()
    uvicorn.run(create_app(settings, cfg), host=args.host, port=args.port, log_level="warning")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="geofill", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("fill", help="fill the hole of TARGET with content from SOURCE")
    p.add_argument("--target", required=True, help="image with the hole (PNG/JPEG/WebP/TIFF)")
    p.add_argument(
        "--mask", required=True, help="hole mask, same size as target: pixel >= 127 (or alpha) = hole"
    )
    p.add_argument("--source", required=True, help="another photo of the same scene")
    p.add_argument("-o", "--output", required=True, help="output image (written atomically)")
    p.add_argument("--debug-dir", help="write matches, depth, warped source, coverage and report.json here")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress messages")
    _add_config_flags(p)
    p.set_defaults(func=cmd_fill)

    p = sub.add_parser("demo", help="fill a self-generated synthetic scene and report its numbers")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("serve", help="web page and REST API: brush the hole, add references, fill")
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)"
    )
    p.add_argument("--port", type=int, default=8080)
    p.add_argument("--open", action="store_true", help="open the page in the default browser")
    p.add_argument("--workers", type=int, help="fills at once (default: one per 2 cores)")
    p.add_argument("--queue", type=int, default=8, help="jobs waiting at most before 429 (default 8)")
    p.add_argument(
        "--job-ttl", type=float, default=3600.0, metavar="S", help="job lifetime after it ends (s)"
    )
    p.add_argument("--max-upload-mb", type=float, default=50.0, help="largest uploaded file (MiB)")
    p.add_argument("--max-pixels", type=int, default=40_000_000, help="largest image (pixels)")
    p.add_argument("--max-sources", type=int, default=8, help="most reference photos per fill")
    p.add_argument("--config", help="JSON config file: the defaults of every fill")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a default config key")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("config", help="print the configuration (defaults + overrides) as JSON")
    _add_config_flags(p)
    p.set_defaults(func=cmd_config)

    sub.add_parser("eval", help="evaluate methods on image pairs (see `geofill eval --help`)", add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["eval"]:
        from .evaluation.cli import main_eval

        return main_eval(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except GeoFillError as exc:
        print(f"geofill: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("geofill: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
