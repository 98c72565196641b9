"""``geofill models list|download|verify``: every model file geofill can use, where it would be
resolved from, its size and checksum.

A fill never downloads (``depth.download`` and ``inpaint.download`` are off by default): a model
missing from the cache is a file-system check and the weight-free default is used, with the
reason in the report. ``models download`` is the step that reaches for the network, with a
progress bar, and refuses a file whose size or SHA-256 differs from the pinned one. A file without
a published checksum (LaMa, DPT-Hybrid, MiDaS) is downloaded and used unverified, and every report
and ``models list`` line says so."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

from .config import FillConfig, parse_overrides
from .errors import GeoFillError
from .extras import available, install_hint
from .weights import (
    ResolvedWeights,
    WeightsSpec,
    WeightsUnavailable,
    cache_dir,
    download,
    hub_offline,
    resolve_weights,
    sha256_of,
)


@dataclass(frozen=True)
class ModelEntry:
    """One model file: what uses it, and the config key of its explicit path."""

    name: str
    spec: WeightsSpec
    used_for: str
    path_key: str

    def explicit_path(self, cfg: FillConfig) -> str | None:
        """The explicit path the configuration gives this file (depth.model_path names the file of
        the selected ``depth.model`` only)."""
        if self.path_key == "depth.model_path":
            return cfg.depth.model_path if cfg.depth.model == self.name else None
        if self.path_key == "matching.learned_model":
            return cfg.matching.learned_model
        return cfg.inpaint.lama_model


def registry() -> list[ModelEntry]:
    """Every model file geofill can use."""
    from .composite.inpaint import LAMA_WEIGHTS
    from .depth.onnx import MODELS
    from .match.learned import MATCHER_WEIGHTS

    entries = [
        ModelEntry(name, m.weights, f"learned depth (depth.model = {name})", "depth.model_path")
        for name, m in MODELS.items()
    ]
    return [
        *entries,
        ModelEntry("lama", LAMA_WEIGHTS, "single-image inpainting (inpaint.method)", "inpaint.lama_model"),
        ModelEntry(
            "superpoint-lightglue",
            MATCHER_WEIGHTS,
            "learned matching rung (matching.learned)",
            "matching.learned_model",
        ),
    ]


def _entry(name: str) -> ModelEntry:
    for e in registry():
        if e.name == name:
            return e
    known = ", ".join(e.name for e in registry())
    raise GeoFillError(f"unknown model {name!r}; known: {known}")


def _where(spec: WeightsSpec) -> str:
    if spec.url:
        return spec.url
    return f"hub {spec.repo_id} {spec.filename} @ {spec.revision[:12]}"


def _checksum(spec: WeightsSpec) -> str:
    if spec.sha256:
        return f"sha256 {spec.sha256}"
    if spec.size:
        return f"size {spec.size} bytes (no published SHA-256)"
    return "no published checksum: cannot be verified"


def _resolution(entry: ModelEntry, cfg: FillConfig) -> ResolvedWeights | WeightsUnavailable:
    return resolve_weights(entry.spec, entry.explicit_path(cfg), allow_download=False)


def cmd_list(args: argparse.Namespace, cfg: FillConfig) -> int:
    runtime = "installed" if available("onnxruntime") else f"NOT installed ({install_hint('onnxruntime')})"
    print(f"onnxruntime (runs every model below): {runtime}")
    downloads = "off (HF_HUB_OFFLINE)" if hub_offline() else "geofill models download NAME"
    print(f"cache: {cache_dir()}; downloads: {downloads}")
    for e in registry():
        got = _resolution(e, cfg)
        size = f"{e.spec.size / 1e6:.0f} MB" if e.spec.size else "size unknown"
        print(f"{e.name}: {e.spec.name}, {e.spec.license}; {e.used_for}")
        print(f"  resolves in order: {e.path_key}, ${e.spec.env_var}, cache, download from {_where(e.spec)}")
        print(f"  {size}; {_checksum(e.spec)}")
        if isinstance(got, ResolvedWeights):
            print(f"  found: {got.describe()}")
        else:
            print(f"  not found: {got.reason}")
    list_packaged()
    return 0


def list_packaged() -> None:
    """The weights that ship inside an installed package (nothing to download or cache)."""
    from .match import xfeat

    print(
        f"{xfeat.NAME}: {xfeat.LICENSE}; learned matching rung (matching.learned_matcher = xfeat-lighterglue)"
    )
    missing = xfeat.missing_modules()
    if missing:
        print(f"  not installed (missing {', '.join(missing)}): {xfeat.INSTALL}")
        return
    for w in xfeat.shipped_weights():
        check = "matches the pinned SHA-256" if w.verified else f"DIFFERS from the pinned {w.expected_sha256}"
        print(f"  {w.filename}: from the {w.origin} ({w.path}); sha256 {w.sha256} ({check})")


def cmd_download(args: argparse.Namespace, cfg: FillConfig) -> int:
    import http.client  # 13 ms of every command if imported with the module

    names = [e.name for e in registry()] if args.name == "all" else [args.name]
    for name in names:
        e = _entry(name)
        got = _resolution(e, cfg)
        if isinstance(got, ResolvedWeights) and not args.force:
            print(f"{name}: already there: {got.describe()}")
            continue
        if hub_offline():
            raise GeoFillError(f"{name}: downloads disabled by HF_HUB_OFFLINE")
        dest = e.spec.cache_path(cache_dir())
        print(f"{name}: downloading from {e.spec.download_url()} to {dest}", file=sys.stderr)
        try:
            download(e.spec, dest, progress_bar=True)
        except (OSError, ValueError, http.client.HTTPException) as exc:
            raise GeoFillError(f"{name}: download failed: {' '.join(str(exc).split())}") from exc
        note = "verified" if e.spec.sha256 or e.spec.size else "NOT verified: no published checksum"
        print(f"{name}: {dest} ({note}; sha256 {sha256_of(dest)})")
    return 0


def cmd_verify(args: argparse.Namespace, cfg: FillConfig) -> int:
    entries = registry() if args.name in (None, "all") else [_entry(args.name)]
    bad = 0
    for e in entries:
        got = _resolution(e, cfg)
        if isinstance(got, WeightsUnavailable):
            print(f"{e.name}: not found ({got.reason})")
            continue
        digest = sha256_of(got.path)
        size = got.path.stat().st_size
        if e.spec.sha256 is not None:
            ok = digest == e.spec.sha256
            verdict = (
                "OK (SHA-256 matches)" if ok else f"MISMATCH: SHA-256 {digest}, expected {e.spec.sha256}"
            )
        elif e.spec.size is not None:
            ok = size == e.spec.size
            verdict = (
                "size matches (no published SHA-256)"
                if ok
                else f"MISMATCH: {size} bytes, expected {e.spec.size}"
            )
        else:
            ok, verdict = True, "cannot be verified: no published checksum"
        bad += not ok
        print(f"{e.name}: {got.path} ({size} bytes, sha256 {digest}): {verdict}")
    return 2 if bad else 0


def add_models_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("models", help="list, download or verify the model files geofill can use")
    p.add_argument(
        "--config", help="JSON config file (explicit model paths: depth.model_path, inpaint.lama_model)"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config key")
    msub = p.add_subparsers(dest="models_command", required=True)
    msub.add_parser("list", help="every model, where it resolves from, size and checksum")
    d = msub.add_parser("download", help="download a model into the cache (with a progress bar)")
    d.add_argument("name", help="model name (see `geofill models list`) or 'all'")
    d.add_argument("--force", action="store_true", help="download even when a usable file is found")
    v = msub.add_parser("verify", help="hash the files found and compare with the published checksums")
    v.add_argument("name", nargs="?", help="model name (default: all)")
    p.set_defaults(func=cmd_models)


def cmd_models(args: argparse.Namespace) -> int:
    cfg = FillConfig.from_json(args.config) if args.config else FillConfig()
    overrides = parse_overrides(args.set)
    cfg = cfg.updated(overrides) if overrides else cfg
    handler = {"list": cmd_list, "download": cmd_download, "verify": cmd_verify}[args.models_command]
    return handler(args, cfg)
