"""Command line: ``geofill fill``, ``geofill batch``, ``geofill serve``, ``geofill demo``,
``geofill eval``, ``geofill config``, ``geofill models``.

Every user-facing problem is one line on stderr and a non-zero exit status, with nothing written.
SIGTERM is turned into an exception, so an output being written is removed like on any error."""

from __future__ import annotations

import argparse
import gc
import os
import signal
import sys
import time
import typing
from pathlib import Path

from .config import PRESETS, Cost, DepthConfig, FillConfig, choices, marked_keys, parse_overrides
from .errors import (
    EXIT_FELL_BACK,
    EXIT_ITEMS_FAILED,
    EXIT_OUT_OF_MEMORY,
    ConfigError,
    GeoFillError,
    OutputError,
    Terminated,
)
from .formats import FORMAT_SUFFIXES
from .progress import Progress

#: What ``geofill --help`` says the program is (plain text: argparse prints it as it is).
DESCRIPTION = "Fill a hole in a photo with what other photos of the same scene show."

_ALLOW_FALLBACK_HELP = (
    f"exit 0 even when a fill falls back to single-image inpainting (default: exit {EXIT_FELL_BACK})"
)


def _config_from_args(args: argparse.Namespace) -> FillConfig:
    cfg = FillConfig.from_json(args.config) if args.config else FillConfig()
    if getattr(args, "preset", None):
        cfg = cfg.preset(args.preset)
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
        "--preset",
        choices=sorted(PRESETS),
        help="named configuration applied on top of --config: the paper's settings and ablations",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config key, e.g. depth.backend=file"
    )
    p.add_argument(
        "--depth",
        choices=choices(DepthConfig, "backend"),
        help="depth backend (default: auto = fused when learned-depth weights resolve, else stereo)",
    )
    p.add_argument(
        "--depth-model", metavar="PATH", help="ONNX file of the learned depth model (depth.model) to use"
    )
    p.add_argument("--depth-file", help="depth/disparity map of the SOURCE (.npy, 16-bit PNG, TIFF, EXR)")
    p.add_argument("--depth-kind", choices=choices(DepthConfig, "file_kind"), help="what --depth-file holds")
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


def _quality(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if not 1 <= value <= 100:
        raise argparse.ArgumentTypeError(f"expected an integer from 1 to 100, got {text!r}")
    return value


_OVERWRITE_HELP = "allow an output to replace an input file (the target photo, say); refused otherwise"


def cmd_fill(args: argparse.Namespace) -> int:
    from .debug import write_debug
    from .io import (
        LOSSY_SUFFIXES,
        check_output_dir,
        check_output_path,
        file_id,
        read_image,
        read_mask,
        read_reference_mask,
        validate_pair,
        write_image_atomic,
    )
    from .pipeline import fill_loaded
    from .preflight import check_resources

    started = time.perf_counter()
    cfg = _config_from_args(args)
    check_output_path(args.output)
    lossy = Path(args.output).suffix.lower() in LOSSY_SUFFIXES
    if args.quality is not None and not lossy:
        raise ConfigError(f"{args.output}: --quality applies to JPEG and WebP output only")
    if args.debug_dir:
        check_output_dir(args.debug_dir)
    source_paths, mask_paths = reference_paths(args.source or [], args.sources, args.source_mask)
    inputs = [("--target", args.target), ("--mask", args.mask), ("--depth-file", cfg.depth.file_path)]
    inputs += [("--source", p) for p in source_paths] + [("--source-mask", m) for m in mask_paths if m]
    out_id = file_id(args.output)
    replaced = next((f"{flag} {p}" for flag, p in inputs if p and out_id and file_id(p) == out_id), None)
    if replaced is not None and not args.overwrite:
        raise OutputError(
            f"{args.output}: is the {replaced}; the output would replace it "
            "(give another -o, or --overwrite to replace it)"
        )
    target = read_image(args.target, max_pixels=cfg.max_pixels, min_side=cfg.min_side_px)
    sources = [read_image(p, max_pixels=cfg.max_pixels, min_side=cfg.min_side_px) for p in source_paths]
    mask = read_mask(args.mask, max_pixels=cfg.max_pixels)
    # Validated here too so that errors name the files rather than "target"/"mask".
    for path, source in zip(source_paths, sources, strict=True):
        validate_pair(
            target.pixels,
            mask,
            source.pixels,
            min_side=cfg.min_side_px,
            max_pixels=cfg.max_pixels,
            max_mask_fraction=cfg.max_mask_fraction,
            names=(args.target, args.mask, str(path)),
        )
    source_masks = [
        None if m is None else read_reference_mask(m, source.pixels, str(path), max_pixels=cfg.max_pixels)
        for path, source, m in zip(source_paths, sources, mask_paths, strict=True)
    ]
    # The depth file and the depth model belong to the (first) reference the depth stage runs on.
    check_resources(cfg, (sources[0].pixels.shape[1], sources[0].pixels.shape[0]))
    prog = Progress(quiet=args.quiet, time_budget_s=cfg.time_budget_s, verbose=args.verbose)
    if lossy:
        prog.say(
            f"note: {Path(args.output).suffix} output re-encodes every pixel, those outside the hole too; "
            "use PNG or TIFF to keep them byte-identical"
        )
    metadata = target.metadata.stripped() if args.strip_metadata else target.metadata
    if metadata.note:
        prog.say(f"note: {args.target}: {metadata.note}")
    for image in (target, *sources):
        if image.metadata.unread:
            prog.say(f"note: {image.path}: {image.metadata.unread}")
    for path, m, masked in zip(source_paths, mask_paths, source_masks, strict=True):
        if masked is not None:
            prog.say(f"{path}: {100 * masked.mean():.0f}% of it is never copied (masked by {m})")
    names = [Path(p).name for p in source_paths]
    result = fill_loaded(
        target, mask, sources, cfg, source_masks=source_masks, source_names=names, progress=prog
    )
    write_image_atomic(args.output, result.image, metadata=metadata, quality=args.quality)
    if args.debug_dir:
        write_debug(args.debug_dir, result, mask, cfg)
    r = result.report
    refused = r.refused_words(names)
    prog.say(
        f"wrote {args.output} in {time.perf_counter() - started:.1f} s: "
        f"{r.filled_words(names)}" + (f"; {refused}" if refused else "")
    )
    if r.status == "reference" or args.allow_fallback:
        return 0
    # Said even with --quiet: a script must be able to tell this from a fill from the source.
    print(
        f"geofill: no reference photo could be used, the whole hole was painted from its surroundings "
        f"({'; '.join(r.dropped_words()) or 'the references supplied no pixel'}); "
        f"exit status {EXIT_FELL_BACK} (--allow-fallback accepts it)",
        file=sys.stderr,
    )
    return EXIT_FELL_BACK


def cmd_batch(args: argparse.Namespace) -> int:
    from .batch import BatchSettings, items_from_folders, read_manifest, run_batch
    from .io import LOSSY_SUFFIXES

    cfg = _config_from_args(args)
    if args.quality is not None and args.format and FORMAT_SUFFIXES[args.format] not in LOSSY_SUFFIXES:
        raise ConfigError(f"--quality applies to JPEG and WebP output only, not --format {args.format}")
    if args.manifest:
        if args.images or args.masks or args.sources or args.sources_per_image:
            raise ConfigError("--manifest names every file: give it without --images/--masks/--sources")
        items = read_manifest(Path(args.manifest), cfg, output_format=args.format)
    else:
        if not (args.images and args.masks):
            raise ConfigError("give --images and --masks (or a --manifest)")
        items = items_from_folders(
            Path(args.images),
            Path(args.masks),
            sources=Path(args.sources) if args.sources else None,
            sources_per_image=Path(args.sources_per_image) if args.sources_per_image else None,
            max_refs=args.max_refs,
            output_format=args.format,
        )
    settings = BatchSettings(
        out_dir=Path(args.out),
        jobs=args.jobs or len(os.sched_getaffinity(0)),
        resume=args.resume,
        allow_fallback=args.allow_fallback,
        ray=args.ray,
        quiet=args.quiet,
        quality=args.quality,
        strip_metadata=args.strip_metadata,
        overwrite=args.overwrite,
    )
    return run_batch(items, cfg, settings).exit_code


def reference_paths(
    files: list[str], folder: str | None, file_masks: dict[int, str] | None = None
) -> tuple[list[Path], list[Path | None]]:
    """The reference photos and their masks: each ``--source`` file (with the ``--source-mask``
    given after it, by index in ``file_masks``), then every image in ``--sources DIR`` (sorted by
    name; ``<stem>.mask.png`` beside a reference is its mask, not a reference). None at all is an
    input error."""
    from .errors import InputError
    from .io import IMAGE_SUFFIXES, split_reference_masks

    paths = [Path(f) for f in files]
    masks: list[Path | None] = [
        Path(file_masks[i]) if i in (file_masks or {}) else None for i in range(len(paths))
    ]
    if folder is not None:
        d = Path(folder)
        if not d.is_dir():
            raise InputError(f"--sources {folder}: not a folder")
        found = sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        found, beside = split_reference_masks(found)
        if not found:
            raise InputError(f"--sources {folder}: no image files ({', '.join(sorted(IMAGE_SUFFIXES))})")
        paths += found
        masks += [beside.get(p) for p in found]
    if not paths:
        raise InputError("no reference photo: give --source FILE (repeatable) or --sources DIR")
    return paths, masks


class _SourceMask(argparse.Action):
    """``--source-mask FILE``: the mask of the ``--source`` given just before it."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # type: ignore[override]
        sources = getattr(namespace, "source", None) or []
        masks = dict(getattr(namespace, self.dest, None) or {})
        if not sources:
            raise argparse.ArgumentError(
                self, f"{values}: no --source before it (give it right after the --source it masks)"
            )
        if len(sources) - 1 in masks:
            raise argparse.ArgumentError(
                self,
                f"{values}: --source {sources[-1]} has a mask already ({masks[len(sources) - 1]}); "
                "one --source-mask per --source, right after it",
            )
        masks[len(sources) - 1] = values
        setattr(namespace, self.dest, masks)


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
        # target, mask, and each reference with its mask
        max_request_bytes=int(args.max_upload_mb * 1024 * 1024) * (2 * args.max_sources + 2),
        max_pixels=args.max_pixels,
        max_sources=args.max_sources,
        caps=_parse_caps(args.cap),
        disk_cap_bytes=int(args.disk_cap_mb * 1024 * 1024),
    )
    app = create_app(settings, cfg)  # before the message: a bad --cap is a one-line error
    url = f"http://{args.host}:{args.port}/"
    print(f"geofill: serving on {url} ({settings.workers} worker(s); Ctrl+C to stop)", file=sys.stderr)
    if args.open:
        import threading
        import webbrowser

        threading.Timer(1.5, webbrowser.open, (url,)).start()
    # No websocket routes: "none" spares importing a websocket library where one is installed.
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning", ws="none")
    return 0


def _parse_caps(items: list[str] | None) -> dict[str, object]:
    """``--cap KEY=VALUE`` flags as {key: value}; the server checks keys and values."""
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--cap expects KEY=VALUE, got {item!r}")
    return parse_overrides(items)


_CAP_HELP = (
    "the most a request may set a setting that scales a fill's cost to (repeatable); a request may "
    "lower it, never raise it (422 naming the key and the cap). Default: the server's own config "
    "value (--config/--set), which a lower cap lowers too; 0 allows any value where 0 means no limit "
    "(matching.max_features, ...). Keys: %(cost_keys)s"
)


class _CostKeys:
    """The cost keys, listed only when ``geofill serve --help`` is printed: walking the config's
    type hints is about a tenth of what importing the CLI and building its parser take (0.11-0.16 s
    against 1.5-1.9 s, 5 runs on a loaded 2-core machine), which every command would pay."""

    def __str__(self) -> str:
        return ", ".join(marked_keys(Cost))


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors as one line (``--help`` still shows the usage)."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"geofill: error: {self.prog.removeprefix('geofill ')}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="geofill", description=DESCRIPTION)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("fill", help="fill the hole of TARGET with content from one or more SOURCE photos")
    p.add_argument("--target", required=True, help="image with the hole (PNG/JPEG/WebP/TIFF)")
    p.add_argument(
        "--mask", required=True, help="hole mask, same size as target: pixel >= 127 (or alpha) = hole"
    )
    p.add_argument(
        "--source",
        action="append",
        metavar="FILE",
        help="another photo of the same scene (repeatable; a --source-mask right after it masks it)",
    )
    p.add_argument(
        "--source-mask",
        action=_SourceMask,
        metavar="FILE",
        help="mask of the --source given just before it: what must never be copied from that photo "
        "(a passer-by, a parked car); same size as that photo, pixel >= 127 (or alpha) = masked",
    )
    p.add_argument(
        "--sources",
        metavar="DIR",
        help="every image in DIR is a reference photo; DIR/<stem>.mask.png (any image format) is the mask "
        "of DIR/<stem>.jpg, not a reference",
    )
    p.add_argument("-o", "--output", required=True, help="output image (written atomically)")
    p.add_argument("--debug-dir", help="write matches, depth, warped source, coverage and report.json here")
    p.add_argument(
        "--quality",
        type=_quality,
        metavar="1-100",
        help="JPEG/WebP output quality (default: a JPEG target's own quantisation tables, else 95); "
        "lossy output re-encodes the pixels outside the hole",
    )
    p.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    p.add_argument(
        "--strip-metadata",
        action="store_true",
        help="do not copy the target's EXIF (GPS included) and ICC profile into the output",
    )
    talk = p.add_mutually_exclusive_group()
    talk.add_argument("-q", "--quiet", action="store_true", help="no progress messages")
    talk.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="also every stage's time and technical summary, per reference (as in --debug-dir's report.json)",
    )
    p.add_argument("--allow-fallback", action="store_true", help=_ALLOW_FALLBACK_HELP)
    _add_config_flags(p)
    p.set_defaults(func=cmd_fill)

    p = sub.add_parser(
        "batch",
        help="fill many images: folders matched by stem or a manifest; parallel, resumable, Ray",
        description="Fill every image of --images (its mask: same stem in --masks, or one mask file for "
        "all) or every row of --manifest, writing OUT/{stem}.{its extension} (the photo's own format, "
        "JPEG at its own quantisation tables, EXIF and ICC profile kept; --format to choose) and "
        "OUT/results.jsonl. A reference's "
        "mask (what must never be copied from it: a passer-by, a parked car) is <ref stem>.mask.png beside "
        "it (any image format; never a target or reference itself), or the manifest's source_masks "
        "column. Exit status: 0 when "
        f"every item was filled from a reference, {EXIT_FELL_BACK} when some fell back to single-image "
        f"inpainting (unless --allow-fallback), {EXIT_ITEMS_FAILED} when some failed, 130 on Ctrl-C, "
        "143 on SIGTERM (the finished items are kept in results.jsonl either way, and --resume runs "
        "the others).",
    )
    p.add_argument("--images", metavar="DIR", help="folder of target images")
    p.add_argument(
        "--masks", metavar="DIR|FILE", help="folder of masks (matched by stem) or one mask for all"
    )
    refs = p.add_mutually_exclusive_group()
    refs.add_argument(
        "--sources",
        metavar="DIR",
        help="other photos of the shoot: the best --max-refs per target are used; DIR/<stem>.mask.png "
        "masks what must never be copied from DIR/<stem>.jpg",
    )
    refs.add_argument(
        "--sources-per-image",
        metavar="DIR",
        help="DIR/<stem>/ holds each image's references (and their masks, <ref stem>.mask.png)",
    )
    refs.add_argument(
        "--manifest",
        metavar="FILE",
        help="CSV or JSONL: target, mask, sources, optional source_masks, output and set",
    )
    p.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="output folder (created if missing); one that holds input files is refused without --overwrite",
    )
    p.add_argument(
        "--format",
        choices=sorted(FORMAT_SUFFIXES),
        help="output format of every item (default: each target's own; a manifest's output name wins)",
    )
    p.add_argument(
        "--quality",
        type=_quality,
        metavar="1-100",
        help="JPEG/WebP output quality (default: a JPEG target's own quantisation tables, else 95)",
    )
    p.add_argument(
        "--strip-metadata",
        action="store_true",
        help="do not copy each target's EXIF (GPS included) and ICC profile into its output",
    )
    p.add_argument("--overwrite", action="store_true", help=_OVERWRITE_HELP)
    p.add_argument(
        "--max-refs", type=int, default=3, metavar="N", help="references picked per target with --sources (3)"
    )
    p.add_argument("--jobs", type=int, metavar="N", help="worker processes (default: the number of cores)")
    p.add_argument("--resume", action="store_true", help="skip items whose output is complete")
    p.add_argument("--allow-fallback", action="store_true", help=_ALLOW_FALLBACK_HELP)
    p.add_argument(
        "--ray",
        metavar="auto|ADDRESS|local",
        help="run on a Ray cluster (extra geofill[ray]): auto = the running cluster, local = start one here",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or per-item lines")
    _add_config_flags(p)
    p.set_defaults(func=cmd_batch)

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
    # argparse fills %(cost_keys)s from the action's attributes as it prints the help
    p.add_argument("--cap", action="append", metavar="KEY=VALUE", help=_CAP_HELP).cost_keys = _CostKeys()
    p.add_argument(
        "--disk-cap-mb",
        type=float,
        default=2048.0,
        metavar="MB",
        help="disk space (MiB) of all jobs' files (uploads in flight counted at their largest); over it "
        "the oldest finished jobs' results are deleted (their status says so, their result is 410), and "
        "with none left a new upload is a 429 (default 2048)",
    )
    p.add_argument(
        "--config", help="JSON config file: the defaults of every fill, and of the caps (see --cap)"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a default config key")
    p.set_defaults(func=cmd_serve)

    p = sub.add_parser("config", help="print the configuration (defaults + overrides) as JSON")
    _add_config_flags(p)
    p.set_defaults(func=cmd_config)

    sub.add_parser("eval", help="evaluate methods on image pairs (see `geofill eval --help`)", add_help=False)

    from .models import add_models_parser

    add_models_parser(sub)
    return parser


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["eval"]:
        from .evaluation.cli import main_eval

        return main_eval(argv[1:])
    args = build_parser().parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return args.func(args)
    except GeoFillError as exc:
        print(f"geofill: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except MemoryError as exc:
        # numpy's message names the allocation that failed; the atomic write leaves no half output.
        said = f": {exc}" if str(exc) else ""
        print(f"geofill: error: out of memory{said}; nothing was written", file=sys.stderr)
        return EXIT_OUT_OF_MEMORY
    except KeyboardInterrupt:
        print("geofill: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print("geofill: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    finally:
        signal.signal(signal.SIGTERM, previous)


def run() -> typing.NoReturn:
    """The ``geofill`` command: :func:`main`, then exit with its status."""
    code = main()
    # Whatever is alive now lives until the process ends: frozen, it is skipped by the garbage
    # collection passes of the interpreter's exit, which took 0.2 s after a fill (numba's and
    # the pipeline's objects) against 0.03 s frozen.
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    run()
