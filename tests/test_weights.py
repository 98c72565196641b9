"""Weights resolution: explicit path > environment variable > cache > hub download, and every failure
(corrupt, truncated, offline, unreachable) as a reason, against a local HTTP server in the hub's layout."""

from __future__ import annotations

import hashlib
import http.server
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from geofill import weights as W
from geofill.weights import ResolvedWeights, WeightsSpec, WeightsUnavailable, resolve_weights

PAYLOAD = bytes(range(256)) * 400  # 102400 bytes
SHA = hashlib.sha256(PAYLOAD).hexdigest()
REPO, FILE, REV = "org/tiny-depth", "onnx/model.onnx", "0123456789abcdef0123456789abcdef01234567"


class HubServer:
    """Serves ``/{REPO}/resolve/{REV}/{FILE}`` like the hub; ``mode`` picks the body:
    ``ok``, ``corrupt`` (right length, wrong bytes), ``truncated`` (announces more than it sends)
    or ``missing`` (404). Counts the requests it answered."""

    def __init__(self, mode: str = "ok"):
        self.mode, self.requests = mode, 0
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):
                server.requests += 1
                if self.path != f"/{REPO}/resolve/{REV}/{FILE}" or server.mode == "missing":
                    self.send_error(404)
                    return
                body = PAYLOAD if server.mode != "corrupt" else PAYLOAD[::-1]
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body[: len(body) // 2] if server.mode == "truncated" else body)

            def log_message(self, *args):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.endpoint = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True).start()

    def close(self):
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def hub():
    server = HubServer()
    yield server
    server.close()


@pytest.fixture
def env(monkeypatch, tmp_path):
    """A fresh cache, downloads allowed, no explicit-path variable."""
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)
    monkeypatch.delenv("GEOFILL_TEST_WEIGHTS", raising=False)
    return tmp_path


SPEC = WeightsSpec(
    "tiny test model", FILE, repo_id=REPO, revision=REV, sha256=SHA, env_var="GEOFILL_TEST_WEIGHTS"
)


@pytest.mark.needs("huggingface_hub")
def test_download_verifies_caches_and_is_reused(hub, env):
    got = resolve_weights(SPEC, endpoint=hub.endpoint)
    assert isinstance(got, ResolvedWeights), got
    assert got.source == "download" and got.verified
    assert got.path == SPEC.cache_path(env / "cache") and got.path.read_bytes() == PAYLOAD
    again = resolve_weights(SPEC, endpoint=hub.endpoint)
    assert isinstance(again, ResolvedWeights) and again.source == "cache" and again.verified
    assert hub.requests == 1  # the second resolution did not touch the network


@pytest.mark.needs("huggingface_hub")
def test_hub_endpoint_from_environment(hub, env, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", hub.endpoint)
    assert SPEC.download_url() == f"{hub.endpoint}/{REPO}/resolve/{REV}/{FILE}"
    got = resolve_weights(SPEC)
    assert isinstance(got, ResolvedWeights) and got.source == "download"


@pytest.mark.needs("huggingface_hub")
def test_order_explicit_then_env_then_cache(hub, env, monkeypatch):
    assert isinstance(resolve_weights(SPEC, endpoint=hub.endpoint), ResolvedWeights)  # now cached
    by_env = env / "from_env.onnx"
    by_env.write_bytes(b"env")
    explicit = env / "explicit.onnx"
    explicit.write_bytes(b"explicit")
    monkeypatch.setenv("GEOFILL_TEST_WEIGHTS", str(by_env))
    got = resolve_weights(SPEC, explicit, endpoint=hub.endpoint)
    assert got.source == "explicit" and got.path == explicit and not got.verified
    got = resolve_weights(SPEC, endpoint=hub.endpoint)
    assert got.source == "env" and got.path == by_env
    monkeypatch.delenv("GEOFILL_TEST_WEIGHTS")
    assert resolve_weights(SPEC, endpoint=hub.endpoint).source == "cache"
    assert hub.requests == 1


def test_missing_explicit_path_is_unavailable_with_reason(env):
    got = resolve_weights(SPEC, env / "nope.onnx")
    assert isinstance(got, WeightsUnavailable)
    assert "explicit path" in got.reason and "nope.onnx" in got.reason


@pytest.mark.needs("huggingface_hub")
@pytest.mark.parametrize(
    ("mode", "words"), [("corrupt", "SHA-256"), ("truncated", "truncated"), ("missing", "HTTP 404")]
)
def test_bad_download_is_refused_and_not_cached(env, mode, words):
    server = HubServer(mode)
    try:
        got = resolve_weights(SPEC, endpoint=server.endpoint)
    finally:
        server.close()
    assert isinstance(got, WeightsUnavailable)
    assert words in got.reason and "download failed" in got.reason
    folder = SPEC.cache_path(env / "cache").parent
    assert not folder.exists() or not any(folder.iterdir())  # no partial or corrupt file left


@pytest.mark.needs("huggingface_hub")
def test_size_only_spec_rejects_wrong_size(hub, env):
    spec = WeightsSpec("sized", FILE, repo_id=REPO, revision=REV, size=len(PAYLOAD) + 1)
    got = resolve_weights(spec, endpoint=hub.endpoint)
    assert isinstance(got, WeightsUnavailable) and "expected" in got.reason


@pytest.mark.needs("huggingface_hub")
def test_unverifiable_spec_is_used_but_says_so(hub, env):
    spec = WeightsSpec("unpinned", FILE, repo_id=REPO, revision=REV)
    got = resolve_weights(spec, endpoint=hub.endpoint)
    assert isinstance(got, ResolvedWeights) and not got.verified
    assert "not verified" in got.describe()


@pytest.mark.needs("huggingface_hub")
def test_corrupt_cache_is_replaced(hub, env):
    path = SPEC.cache_path(env / "cache")
    path.parent.mkdir(parents=True)
    path.write_bytes(PAYLOAD[::-1])
    got = resolve_weights(SPEC, endpoint=hub.endpoint)
    assert isinstance(got, ResolvedWeights) and got.source == "download"
    assert path.read_bytes() == PAYLOAD


def test_offline_mode_forbids_download(hub, env, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    got = resolve_weights(SPEC, endpoint=hub.endpoint)
    assert isinstance(got, WeightsUnavailable)
    assert "HF_HUB_OFFLINE" in got.reason and "not in the cache" in got.reason
    assert hub.requests == 0
    assert "tiny test model weights not available" in str(got)


def test_downloads_disabled_by_configuration(hub, env):
    got = resolve_weights(SPEC, endpoint=hub.endpoint, allow_download=False)
    assert isinstance(got, WeightsUnavailable) and "configuration" in got.reason and hub.requests == 0


@pytest.mark.needs("huggingface_hub")
def test_unreachable_server_is_a_reason_not_a_hang(env):
    server = HubServer()
    endpoint = server.endpoint
    server.close()  # nothing listens on that port any more
    got = resolve_weights(SPEC, endpoint=endpoint)
    assert isinstance(got, WeightsUnavailable) and "cannot reach" in got.reason


@pytest.mark.needs("huggingface_hub")
def test_hub_cache_is_used_when_verified(env, monkeypatch):
    """A file already in the Hugging Face cache layout (models--org--name/snapshots/<rev>/...)."""
    hub_cache = env / "hf"
    snap = hub_cache / "models--org--tiny-depth" / "snapshots" / REV / FILE
    snap.parent.mkdir(parents=True)
    snap.write_bytes(PAYLOAD)
    monkeypatch.setenv("HF_HUB_CACHE", str(hub_cache))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    got = resolve_weights(SPEC)
    assert isinstance(got, ResolvedWeights) and got.source == "hub-cache" and got.verified
    assert Path(got.path) == snap


def test_hub_cache_dir_follows_the_hubs_variables(monkeypatch, tmp_path):
    for var in ("HF_HUB_CACHE", "HUGGINGFACE_HUB_CACHE", "HF_HOME", "XDG_CACHE_HOME"):
        monkeypatch.delenv(var, raising=False)
    assert W.hub_cache_dir() == Path.home() / ".cache" / "huggingface" / "hub"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert W.hub_cache_dir() == tmp_path / "xdg" / "huggingface" / "hub"
    monkeypatch.setenv("HF_HOME", str(tmp_path / "home"))
    assert W.hub_cache_dir() == tmp_path / "home" / "hub"
    monkeypatch.setenv("HUGGINGFACE_HUB_CACHE", str(tmp_path / "legacy"))
    assert W.hub_cache_dir() == tmp_path / "legacy"
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "new"))
    assert W.hub_cache_dir() == tmp_path / "new"


def test_cache_miss_does_not_import_the_hub_client(tmp_path):
    """A miss is a file-system check: a fill on the weight-free default never imports huggingface_hub."""
    code = (
        "import sys; from geofill.weights import resolve_weights, WeightsSpec, WeightsUnavailable\n"
        "got = resolve_weights(WeightsSpec('m', 'f.onnx', repo_id='org/m'), allow_download=False)\n"
        "assert isinstance(got, WeightsUnavailable), got\n"
        "print('huggingface_hub' in sys.modules)"
    )
    env = {**os.environ, "GEOFILL_CACHE": str(tmp_path / "c"), "HF_HUB_CACHE": str(tmp_path / "hf")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_cache_dir_follows_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path))
    assert W.cache_dir() == tmp_path
    monkeypatch.delenv("GEOFILL_CACHE")
    assert W.cache_dir() == Path.home() / ".cache" / "geofill"


@pytest.mark.needs("huggingface_hub")
def test_models_download_shows_progress_verifies_and_is_then_found(hub, env, monkeypatch, capsys):
    from geofill import models
    from geofill.cli import main

    monkeypatch.setenv("HF_ENDPOINT", hub.endpoint)
    monkeypatch.setattr(
        models, "registry", lambda: [models.ModelEntry("tiny", SPEC, "tests", "depth.model_path")]
    )
    assert main(["models", "download", "tiny"]) == 0
    captured = capsys.readouterr()
    assert "100%" in captured.err and "100k" in captured.err  # tqdm's bar reached the whole file
    assert f"tiny: {SPEC.cache_path(env / 'cache')} (verified; sha256 {SHA})" in captured.out
    assert main(["models", "download", "tiny"]) == 0
    assert "tiny: already there: tiny test model from cache" in capsys.readouterr().out
    assert hub.requests == 1
