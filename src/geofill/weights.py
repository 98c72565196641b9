"""Model weights: a named file resolved to a verified local path, or the reason it cannot be.

Order (:func:`resolve_weights`): an explicit path (argument, e.g. ``--depth-model``) -> the spec's
environment variable -> the local cache (geofill's own under ``$GEOFILL_CACHE`` or
``~/.cache/geofill``, then the Hugging Face hub cache) -> a download -> not available. Nothing is
ever used silently: the result says where the file came from and whether it was verified, and
:class:`WeightsUnavailable` carries a one-line reason for the user.

Downloads use the hub's URL layout (``{endpoint}/{repo}/resolve/{revision}/{file}``, built by
``huggingface_hub.hf_hub_url``; the endpoint follows ``HF_ENDPOINT``) or a spec's direct URL, with
a single request through ``urllib``: ``hf_hub_download`` retries a dead network for ~25 s (measured
here, five retries with back-off, not configurable), which an ``auto`` depth choice would pay on
every fill of an offline machine. The body is streamed to a temporary file while its SHA-256 is
computed, checked against the length the server announced and against the spec's size/SHA-256,
and only then renamed into the cache, so a truncated or corrupt download never lands there.
``HF_HUB_OFFLINE=1`` (read at call time) forbids downloads.

``huggingface_hub`` comes with the ``onnx`` extra and is imported only here, when the hub cache is
searched or a file is downloaded: without it the hub cache is skipped (and said so) and a download
is a one-line error naming the extra.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from .extras import available, install_hint, require

#: Seconds without progress before a download gives up.
DOWNLOAD_TIMEOUT_S = 30.0
_TRUE = {"1", "ON", "YES", "TRUE"}
#: (path, size, mtime) of files whose SHA-256 was checked in this process: hashing 100 MB costs
#: ~0.2 s, which every fill would otherwise pay again.
_VERIFIED: set[tuple[str, int, int]] = set()
#: URL -> connection error of this process: a dead network is tried once, not once per fill.
_UNREACHABLE: dict[str, str] = {}


@dataclass(frozen=True)
class WeightsSpec:
    """Where a model file lives and how to recognise it.

    ``repo_id``/``filename``/``revision``: a Hugging Face hub file (pin ``revision`` to a commit
    where possible); ``url``: a direct download instead (e.g. a GitHub release asset), with
    ``filename`` its name in the cache. ``sha256``/``size`` (bytes): the expected file, None where
    no trustworthy value is known (then the file is used unverified, and said so). ``env_var``:
    environment variable holding an explicit path."""

    name: str
    filename: str
    repo_id: str | None = None
    revision: str = "main"
    url: str | None = None
    sha256: str | None = None
    size: int | None = None
    env_var: str | None = None
    license: str = ""

    def download_url(self, endpoint: str | None = None) -> str:
        """The URL the file is downloaded from (the hub's layout unless ``url`` is set)."""
        if self.url:
            return self.url
        if not self.repo_id:
            raise ValueError(f"weights '{self.name}' have neither a hub repo nor a URL")
        require("huggingface_hub", f"downloading {self.name}")
        from huggingface_hub import constants, hf_hub_url

        endpoint = endpoint or os.environ.get("HF_ENDPOINT") or constants.ENDPOINT
        return hf_hub_url(self.repo_id, self.filename, revision=self.revision, endpoint=endpoint.rstrip("/"))

    def cache_path(self, cache_dir: Path) -> Path:
        """Where geofill caches this file under ``cache_dir``."""
        where = self.repo_id.replace("/", "--") if self.repo_id else "url"
        return cache_dir / "weights" / where / self.revision / self.filename


@dataclass(frozen=True)
class ResolvedWeights:
    """A local file for the spec. ``source``: how it was found; ``verified``: its SHA-256 (or, when
    no checksum is known, its size) matched the spec."""

    spec: WeightsSpec
    path: Path
    source: Literal["explicit", "env", "cache", "hub-cache", "download"]
    verified: bool

    def describe(self) -> str:
        check = "verified" if self.verified else "not verified: no known checksum"
        if self.source in ("explicit", "env"):
            check = "given by the user, not checked"
        where = {"env": f"${self.spec.env_var}"}.get(self.source, self.source)
        return f"{self.spec.name} from {where} ({self.path}, {check})"


@dataclass(frozen=True)
class WeightsUnavailable:
    """No usable file; ``reason`` is one line for the user (every step that was tried)."""

    spec: WeightsSpec
    reason: str

    def __str__(self) -> str:
        return f"{self.spec.name} weights not available: {self.reason}"


def cache_dir() -> Path:
    """geofill's cache folder: ``$GEOFILL_CACHE`` or ``~/.cache/geofill``."""
    return Path(os.environ.get("GEOFILL_CACHE") or Path.home() / ".cache" / "geofill")


def hub_offline() -> bool:
    """True when ``HF_HUB_OFFLINE`` is set, read at call time (the hub client reads it once, at import)."""
    return os.environ.get("HF_HUB_OFFLINE", "").upper() in _TRUE


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _check_file(path: Path, spec: WeightsSpec) -> tuple[bool, str]:
    """(matches, problem) of a cached file against the spec's SHA-256 or size."""
    st = path.stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    if spec.size is not None and st.st_size != spec.size:
        return False, f"{path} has {st.st_size} bytes, expected {spec.size}"
    if spec.sha256 is None or key in _VERIFIED:
        return True, ""
    digest = sha256_of(path)
    if digest != spec.sha256:
        return False, f"{path} has SHA-256 {digest[:12]}..., expected {spec.sha256[:12]}..."
    _VERIFIED.add(key)
    return True, ""


def _verified(spec: WeightsSpec) -> bool:
    return spec.sha256 is not None or spec.size is not None


def hub_cache_dir() -> Path:
    """The Hugging Face hub cache as ``huggingface_hub`` finds it: ``$HF_HUB_CACHE``, the legacy
    ``$HUGGINGFACE_HUB_CACHE``, else ``hub`` under ``$HF_HOME`` (default
    ``$XDG_CACHE_HOME/huggingface`` or ``~/.cache/huggingface``), read at call time."""
    home = os.environ.get("HF_HOME") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "huggingface"
    )
    given = os.environ.get("HF_HUB_CACHE") or os.environ.get("HUGGINGFACE_HUB_CACHE")
    return Path(os.path.expandvars(os.path.expanduser(given or os.path.join(home, "hub"))))


def _hub_cache_file(spec: WeightsSpec) -> Path | None:
    if not spec.repo_id or not available("huggingface_hub"):
        return None
    cache = hub_cache_dir()
    # The repo's folder (the hub's documented cache layout) is looked for first: importing
    # huggingface_hub costs ~0.15 s, which a fill whose weights were never downloaded (the
    # weight-free default) must not pay. The hub's own look-up resolves refs and snapshots.
    if not (cache / f"models--{spec.repo_id.replace('/', '--')}").is_dir():
        return None
    from huggingface_hub import try_to_load_from_cache

    found = try_to_load_from_cache(spec.repo_id, spec.filename, cache_dir=cache, revision=spec.revision)
    return Path(found) if isinstance(found, str) and Path(found).is_file() else None


def download(
    spec: WeightsSpec,
    dest: Path,
    endpoint: str | None = None,
    timeout: float = DOWNLOAD_TIMEOUT_S,
    progress_bar: bool = False,
) -> None:
    """Download ``spec`` to ``dest`` atomically; raise ``OSError``/``ValueError`` naming the problem
    (network error, truncated body, size or checksum mismatch) with nothing left at ``dest``.
    ``progress_bar``: a tqdm bar on stderr (tqdm comes with huggingface_hub)."""
    require("huggingface_hub", f"downloading {spec.name}")
    import urllib.request  # with its TLS stack, for downloads only (0.02 s of every fill's imports)

    from . import __version__

    url = spec.download_url(endpoint)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f"{dest.name}.part-{os.getpid()}")
    # Public files only: no token is sent, so none can follow a redirect to another host. The
    # headers are geofill's own: huggingface_hub's (build_hf_headers) first fetch the hub's
    # "agent harnesses" list (a telemetry request, up to 3 s when the hub is slow).
    req = urllib.request.Request(url, headers={"user-agent": f"geofill/{__version__}"})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp, open(tmp, "wb") as out:
            announced = resp.headers.get("Content-Length")
            h, n = hashlib.sha256(), 0
            bar = _progress_bar(spec, announced) if progress_bar else None
            while chunk := resp.read(1 << 20):
                out.write(chunk)
                h.update(chunk)
                n += len(chunk)
                if bar is not None:
                    bar.update(len(chunk))
            if bar is not None:
                bar.close()
        if announced is not None and n != int(announced):
            raise ValueError(f"download of {url} truncated: {n} of {announced} bytes")
        if spec.size is not None and n != spec.size:
            raise ValueError(f"download of {url} has {n} bytes, expected {spec.size}")
        digest = h.hexdigest()
        if spec.sha256 is not None and digest != spec.sha256:
            raise ValueError(
                f"download of {url} has SHA-256 {digest[:12]}..., expected {spec.sha256[:12]}..."
            )
        os.replace(tmp, dest)
    finally:
        tmp.unlink(missing_ok=True)


def _progress_bar(spec: WeightsSpec, announced: str | None):
    from tqdm import tqdm

    total = int(announced) if announced is not None else spec.size
    return tqdm(total=total, unit="B", unit_scale=True, unit_divisor=1024, desc=spec.filename, leave=True)


def resolve_weights(
    spec: WeightsSpec,
    explicit_path: str | Path | None = None,
    *,
    allow_download: bool = True,
    endpoint: str | None = None,
    say: Callable[[str], None] | None = None,
) -> ResolvedWeights | WeightsUnavailable:
    """Resolve ``spec`` in the order of the module docstring. ``explicit_path`` (and the spec's
    environment variable) are trusted as given; cached and downloaded files are checked against
    the spec's SHA-256/size. ``say`` receives progress lines (download start)."""
    for source, given in (("explicit", explicit_path), ("env", os.environ.get(spec.env_var or "") or None)):
        if given:
            path = Path(given).expanduser()
            if not path.is_file():
                where = "explicit path" if source == "explicit" else f"${spec.env_var}"
                return WeightsUnavailable(spec, f"{where} {path} is not a file")
            return ResolvedWeights(spec, path, source, verified=False)
    tried = []
    cached = spec.cache_path(cache_dir())
    for source, path in (
        ("cache", cached if cached.is_file() else None),
        ("hub-cache", _hub_cache_file(spec)),
    ):
        if path is None:
            continue
        ok, problem = _check_file(path, spec)
        if ok:
            return ResolvedWeights(spec, path, source, _verified(spec))
        tried.append(f"cached file rejected ({problem})")
        if source == "cache":
            path.unlink(missing_ok=True)  # ours and wrong: fetch it again
    if not tried:
        tried.append(f"not in the cache ({cached.parent})")
        if spec.repo_id and not available("huggingface_hub"):
            tried.append(f"Hugging Face cache not searched ({install_hint('huggingface_hub')})")
    if hub_offline():
        return WeightsUnavailable(spec, "; ".join([*tried, "downloads disabled by HF_HUB_OFFLINE"]))
    if not allow_download:
        return WeightsUnavailable(spec, "; ".join([*tried, "downloads disabled by the configuration"]))
    url = spec.download_url(endpoint)
    if url in _UNREACHABLE:
        return WeightsUnavailable(spec, "; ".join([*tried, f"download failed: {_UNREACHABLE[url]}"]))
    if say is not None:
        size = f" ({spec.size / 1e6:.0f} MB)" if spec.size else ""
        say(f"downloading {spec.name}{size} from {url}")
    import http.client
    import urllib.error

    try:
        download(spec, cached, endpoint)
    except urllib.error.HTTPError as exc:
        return WeightsUnavailable(
            spec, "; ".join([*tried, f"download failed: HTTP {exc.code} {exc.reason} from {url}"])
        )
    except urllib.error.URLError as exc:
        _UNREACHABLE[url] = f"cannot reach {url}: {exc.reason}"
        return WeightsUnavailable(spec, "; ".join([*tried, f"download failed: {_UNREACHABLE[url]}"]))
    except (OSError, ValueError, http.client.HTTPException) as exc:
        return WeightsUnavailable(spec, "; ".join([*tried, f"download failed: {exc}"]))
    return ResolvedWeights(spec, cached, "download", _verified(spec))
