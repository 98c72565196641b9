"""The REST API of ``geofill serve`` through FastAPI's TestClient: every endpoint and error path, a
real fill of a synthetic scene, cancel, the queue limit and expiry.

Error paths run on a server with no worker (``workers=0``): jobs stay queued, so queue, cancel and
expiry are deterministic and no process is started."""

from __future__ import annotations

import compileall
import dataclasses
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import typing
import zlib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the server extra is not installed")
pytest.importorskip("httpx", reason="FastAPI's TestClient needs httpx")
import psutil
from fastapi.testclient import TestClient
from PIL import ExifTags, Image

from geofill.io import read_image
from geofill.server.app import create_app
from geofill.server.jobs import ServerSettings
from geofill.server.schema import config_fields, flatten, locked_keys
from geofill.synthetic import blanked, make_pair

W, H = 320, 240


def png(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, "PNG")
    return buf.getvalue()


@pytest.fixture(scope="module")
def pair():
    return make_pair(seed=0, width=W, height=H)


@pytest.fixture(scope="module")
def upload(pair):
    """The synthetic pair as multipart files, with a flat magenta 'object' in the target's hole."""
    target = pair.target.copy()
    target[pair.hole] = (255, 0, 255)
    return {
        "target_array": target,
        "target": png(target),
        "mask": png(pair.hole.astype(np.uint8) * 255),
        "source": png(pair.source),
    }


def files(upload, n_sources: int = 1, **replace):
    parts = {"target": upload["target"], "mask": upload["mask"]} | replace
    out = [(name, (f"{name}.png", data)) for name, data in parts.items() if data is not None]
    return out + [("sources", (f"ref{k}.png", upload["source"])) for k in range(n_sources)]


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def idle(tmp_path):
    """A server with no worker: (client, app, clock)."""
    clock = FakeClock()
    settings = ServerSettings(
        workers=0, queue_size=2, job_ttl_s=60.0, max_upload_bytes=400_000, max_pixels=200_000,
        max_sources=3, temp_parent=str(tmp_path),
    )  # fmt: skip
    app = create_app(settings, clock=clock)
    with TestClient(app) as client:
        yield client, app, clock


def wait_for(
    client, job_id: str, states=("done", "failed", "cancelled"), timeout_s: float = 300.0, stage: str = ""
) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        snap = client.get(f"/api/v1/jobs/{job_id}").json()
        reached = not stage or stage == snap["stage"] or stage in snap["stages_done"]
        if snap["state"] in states and reached:
            return snap
        time.sleep(0.1)
    raise AssertionError(f"job still {snap['state']} after {timeout_s} s")


def test_real_fill_through_the_api(tmp_path, upload, pair):
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        r = client.post("/api/v1/fill", files=files(upload, n_sources=2), data={"config": "{}"})
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        assert r.headers["location"] == f"/api/v1/jobs/{job_id}"
        snap = wait_for(client, job_id)
        assert snap["state"] == "done", snap
        assert snap["progress"] == 1.0
        assert {"match", "pose", "render", "composite", "write result"} <= set(snap["stages_done"])
        assert snap["notices"] == []
        assert snap["report"]["hole_pixels"] == int(pair.hole.sum())
        assert len(snap["report"]["references"]) == 2
        rows = {row["label"]: row["fraction"] for row in snap["coverage"]}
        assert rows["reference 1"] + rows["reference 2"] + rows["painted"] == pytest.approx(1.0)
        assert rows["reference 1"] + rows["reference 2"] > 0.5  # the synthetic source sees most of the hole
        assert rows["reference 1"] == pytest.approx(snap["report"]["supplied_fraction"][0])
        assert "% from reference" in snap["summary"] and "% painted" in snap["summary"]

        res = client.get(f"/api/v1/jobs/{job_id}/result")  # a PNG target: PNG back
        assert res.status_code == 200 and res.headers["content-type"] == "image/png"
        assert snap["result_file"] == "result.png"
        out = np.array(Image.open(io.BytesIO(res.content)))
        target = upload["target_array"]
        assert out.shape == target.shape
        assert np.array_equal(out[~pair.hole], target[~pair.hole])  # byte-identical outside the hole
        # the magenta object is gone: the fill is close to the true scene, far from magenta
        hole_err = np.abs(out[pair.hole].astype(int) - pair.target[pair.hole]).mean()
        magenta_err = np.abs(out[pair.hole].astype(int) - (255, 0, 255)).mean()
        assert hole_err < 40 < magenta_err

        cov = np.array(Image.open(io.BytesIO(client.get(f"/api/v1/jobs/{job_id}/coverage").content)))
        assert cov.shape == (H, W, 4)
        assert (cov[~pair.hole, 3] == 0).all() and (cov[pair.hole, 3] > 0).all()
        assert (cov[pair.hole, 1] == 170).mean() == pytest.approx(rows["reference 1"], abs=1e-6)

        # a finished job is deleted at once by DELETE, files included
        folder = app.state.jobs.get(job_id).folder
        assert client.delete(f"/api/v1/jobs/{job_id}").status_code == 200
        assert not folder.exists() and client.get(f"/api/v1/jobs/{job_id}").status_code == 404
    assert list(tmp_path.iterdir()) == []  # the server's folder is gone with it


def test_fallback_is_reported_with_its_reason(tmp_path):
    pair = make_pair(seed=4, width=160, height=120)
    parts = [
        ("target", ("t.png", png(pair.target))),
        ("mask", ("m.png", png(pair.hole.astype(np.uint8) * 255))),
        ("sources", ("s.png", png(pair.source))),
    ]
    config = json.dumps({"render.min_hole_coverage": 1.0})  # this render covers less than all
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        job_id = client.post("/api/v1/fill", files=parts, data={"config": config}).json()["id"]
        snap = wait_for(client, job_id)
        assert snap["state"] == "done" and snap["status"] == "single_image"
        # In plain words for the page; the technical reason is in the report.
        assert snap["fallbacks"] == ["reference 1 was not used: it does not see what is behind the hole"]
        assert snap["report"]["references"][0]["reason"].startswith("it covers only")
        assert snap["summary"] == "100 % painted"
        out = np.array(Image.open(io.BytesIO(client.get(f"/api/v1/jobs/{job_id}/result").content)))
        assert np.array_equal(out[~pair.hole], pair.target[~pair.hole])


def _jpeg_with_lens(a: np.ndarray) -> bytes:
    exif = Image.Exif()
    exif[ExifTags.Base.Make], exif[ExifTags.Base.Model] = "Apple", "iPhone 4S"
    lens = exif.get_ifd(ExifTags.IFD.Exif)
    lens[ExifTags.Base.FocalLength], lens[ExifTags.Base.FocalLengthIn35mmFilm] = 4.28, 35
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, "JPEG", quality=95, exif=exif.tobytes())
    return buf.getvalue()


def test_result_keeps_the_targets_exif_and_progress_only_grows(tmp_path, upload, pair):
    """Three references: the done fraction the API reports never goes back; the result carries
    the target's EXIF, so a fill started again from it has the same focal prior."""
    parts = files(upload, n_sources=3, target=_jpeg_with_lens(upload["target_array"]))
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        t0 = time.monotonic()
        job_id = client.post("/api/v1/fill", files=parts).json()["id"]
        seen = []
        while (snap := client.get(f"/api/v1/jobs/{job_id}").json())["state"] in ("queued", "running"):
            seen.append(snap["progress"])
            time.sleep(0.01)
        wall = time.monotonic() - t0
        assert snap["state"] == "done", snap
        assert seen == sorted(seen) and len(set(seen)) >= 5, seen
        assert 0 < snap["wall_s"] <= wall
        res = client.get(f"/api/v1/jobs/{job_id}/result")
        lossless = client.get(f"/api/v1/jobs/{job_id}/result", params={"format": "png"})
        assert client.get(f"/api/v1/jobs/{job_id}/result", params={"format": "gif"}).status_code == 422
    # A JPEG target comes back as a JPEG at the target's own tables; PNG on request, same pixels
    # up to the JPEG's loss.
    assert res.headers["content-type"] == "image/jpeg", res.headers
    assert 'filename="geofill-result.jpg"' in res.headers["content-disposition"]
    assert snap["result_file"] == "result.jpg"
    assert lossless.headers["content-type"] == "image/png"
    (tmp_path / "result.jpg").write_bytes(res.content)
    (tmp_path / "target.jpg").write_bytes(parts[0][1][1])
    with Image.open(tmp_path / "result.jpg") as got, Image.open(tmp_path / "target.jpg") as given_jpeg:
        assert got.quantization == given_jpeg.quantization
    png = np.array(Image.open(io.BytesIO(lossless.content)))
    jpeg = np.array(Image.open(tmp_path / "result.jpg"))
    assert np.abs(png.astype(int) - jpeg).mean() < 3
    kept, given = read_image(tmp_path / "result.jpg").exif, read_image(tmp_path / "target.jpg").exif
    assert kept == given and kept.focal_mm == 4.28 and kept.body == "Apple iPhone 4S"


def test_cancel_terminates_the_running_worker_and_a_dead_worker_fails_its_job(tmp_path, upload):
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        # the paper's solver runs for minutes: the job is surely still running when cancelled
        config = json.dumps({"optimize": {"solver": "paper"}, "depth.backend": "sparse"})
        job_id = client.post("/api/v1/fill", files=files(upload), data={"config": config}).json()["id"]
        snap = wait_for(client, job_id, states=("running",), timeout_s=120, stage="optimize")
        assert snap["state"] == "running" and "match" in snap["stages_done"]
        (pid,) = app.state.jobs.worker_pids()
        r = client.delete(f"/api/v1/jobs/{job_id}")
        assert r.status_code == 200 and r.json()["state"] == "cancelled"
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
        assert client.get(f"/api/v1/jobs/{job_id}/result").status_code == 409
        # the slot has a fresh worker for the next job
        job2 = client.post("/api/v1/fill", files=files(upload), data={"config": config}).json()["id"]
        assert wait_for(client, job2, states=("running",), timeout_s=120, stage="match")["state"] == "running"
        (pid2,) = app.state.jobs.worker_pids()
        assert pid2 != pid
        # a worker that dies (killed, out of memory) fails its job with the reason; nothing hangs
        os.kill(pid2, signal.SIGKILL)
        snap = wait_for(client, job2, timeout_s=60)
        assert snap["state"] == "failed" and snap["error_kind"] == "crash"
        assert snap["error"] == f"the worker process ended unexpectedly (exit {-signal.SIGKILL})"


def test_queue_limit_is_429_with_retry_after(idle, upload):
    client, _, _ = idle
    for _ in range(2):
        assert client.post("/api/v1/fill", files=files(upload)).status_code == 202
    r = client.post("/api/v1/fill", files=files(upload))
    assert r.status_code == 429 and int(r.headers["retry-after"]) > 0
    assert "queue is full" in r.json()["detail"]


def test_cancel_queued_job_then_expiry_deletes_it(idle, upload, tmp_path):
    client, app, clock = idle
    job_id = client.post("/api/v1/fill", files=files(upload)).json()["id"]
    folder = app.state.jobs.get(job_id).folder
    assert folder.parent.parent == tmp_path and sorted(p.name for p in folder.iterdir()) == [
        "mask", "source-1", "target",
    ]  # fmt: skip
    assert client.get(f"/api/v1/jobs/{job_id}").json()["state"] == "queued"
    assert client.get(f"/api/v1/jobs/{job_id}/result").status_code == 409
    assert client.delete(f"/api/v1/jobs/{job_id}").json()["state"] == "cancelled"
    clock.now += 59.0
    assert app.state.jobs.expire() == 0 and folder.exists()
    clock.now += 1.0
    assert app.state.jobs.expire() == 1
    assert not folder.exists()
    assert client.get(f"/api/v1/jobs/{job_id}").status_code == 404


def test_client_filenames_never_become_paths(idle, upload, tmp_path):
    client, app, _ = idle
    parts = [
        ("target", ("../../escape.png", upload["target"])),
        ("mask", ("/etc/passwd", upload["mask"])),
        ("sources", ("..\\..\\x.png", upload["source"])),
    ]
    job_id = client.post("/api/v1/fill", files=parts).json()["id"]
    everything = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    root = app.state.jobs.root.name
    assert everything == [root, f"{root}/{job_id}"] + [
        f"{root}/{job_id}/{n}" for n in ("mask", "source-1", "target")
    ]


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height RGB pixels and whose data is a few bytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16)) + chunk(b"IEND", b"")
    return b"\x89PNG\r\n\x1a\n" + body


@pytest.mark.parametrize(
    ("parts", "status", "words"),
    [
        ({"target": None}, 400, "'target' (a file) is missing"),
        ({"mask": None}, 400, "'mask' (a file) is missing"),
        ({"sources": 0}, 400, "at least one reference"),
        ({"target": b"not an image at all"}, 400, "target: not a PNG, JPEG, WebP, TIFF or HEIC image"),
        ({"target": "truncated"}, 400, "target: cannot decode image"),
        ({"mask": "small"}, 400, "mask"),
        ({"mask": "empty"}, 400, "no hole"),
        ({"target": "huge-bytes"}, 413, "upload limit of 400000 bytes"),
        (
            {"target": "huge-pixels"},
            413,
            "target: 500x500 = 250000 pixels is over the limit of 200000 pixels (max_pixels)",
        ),
        (
            {"target": "bomb"},
            413,
            "target: 10000000000 pixels is over the limit of 200000 pixels (max_pixels)",
        ),
        ({"sources": 4}, 413, "at most 3 (max_sources)"),
    ],
)
def test_bad_uploads_are_4xx_naming_the_problem(idle, upload, parts, status, words):
    client, app, _ = idle
    special = {
        "truncated": upload["target"][: len(upload["target"]) // 2],
        "small": png(np.full((100, 100), 255, np.uint8)),
        "empty": png(np.zeros((H, W), np.uint8)),
        "huge-bytes": np.random.default_rng(0).integers(0, 255, 500_000, np.uint8).tobytes(),
        "huge-pixels": png(np.zeros((500, 500, 3), np.uint8)),
        "bomb": _png_header(100_000, 100_000),  # over Pillow's own limit: its words are not quoted
    }
    n = parts.pop("sources", 1)
    replace = {k: special.get(v, v) if isinstance(v, str) else v for k, v in parts.items()}
    r = client.post("/api/v1/fill", files=files(upload, n_sources=n, **replace))
    assert r.status_code == status, r.text
    assert words in r.json()["detail"] and r.json()["detail"].count(" pixels") <= 2
    assert app.state.jobs.counts() == {}
    assert list(app.state.jobs.root.iterdir()) == []  # the upload's files are gone


@pytest.mark.parametrize(
    ("config", "words"),
    [
        ("{not json", "config: not valid JSON"),
        ('["a list"]', "expected a JSON object"),
        ('{"depth": {"bakend": "stereo"}}', "unknown config key 'depth.bakend'"),
        ('{"nosuch.key": 1}', "unknown config section 'nosuch'"),
        ('{"depth.backend": "magic"}', "config.depth.backend: 'magic' is not one of"),
        ('{"matching": {"max_features": "many"}}', "config.matching.max_features: expected an integer"),
        ('{"depth": {"model_path": "/etc/passwd"}}', "'depth.model_path' can only be set by whoever starts"),
        ('{"max_pixels": 1e12}', "'max_pixels' can only be set"),
    ],
)
def test_bad_config_is_422_naming_the_key(idle, upload, config, words):
    client, _, _ = idle
    r = client.post("/api/v1/fill", files=files(upload), data={"config": config})
    assert r.status_code == 422, r.text
    assert words in r.json()["detail"]


def test_openapi_lists_the_errors_each_route_returns(idle, upload):
    client, _, _ = idle
    paths = client.get("/openapi.json").json()["paths"]
    job = "/api/v1/jobs/{job_id}"
    listed = {
        ("post", "/api/v1/fill"): {"202", "400", "413", "415", "422", "429"},
        ("get", job): {"200", "404"},
        ("delete", job): {"200", "404"},
        ("get", f"{job}/result"): {"200", "404", "409"},
        ("get", f"{job}/coverage"): {"200", "404", "409"},
    }
    for (method, path), statuses in listed.items():
        responses = paths[path][method]["responses"]
        assert statuses <= set(responses), (method, path, sorted(responses))
        assert all(responses[s].get("description") for s in statuses)
    # and they are the statuses these routes answer with
    assert (
        client.post("/api/v1/fill", content=b"x", headers={"content-type": "text/plain"}).status_code == 415
    )
    unknown = "A" * 32
    assert client.get(f"/api/v1/jobs/{unknown}").status_code == 404
    assert client.delete(f"/api/v1/jobs/{unknown}").status_code == 404
    assert client.get(f"/api/v1/jobs/{unknown}/result").status_code == 404
    queued = client.post("/api/v1/fill", files=files(upload)).json()["id"]
    assert client.get(f"/api/v1/jobs/{queued}/coverage").status_code == 409


def test_malformed_requests_are_4xx(idle, upload):
    client, _, _ = idle
    assert client.post("/api/v1/fill", json={"target": "x"}).status_code == 415
    assert (
        client.post("/api/v1/fill", content=b"x", headers={"content-type": "multipart/form-data"}).status_code
        == 415
    )
    garbage = {"content-type": "multipart/form-data; boundary=zz"}
    assert client.post("/api/v1/fill", content=b"--zz\r\nbroken", headers=garbage).status_code == 400
    assert client.post("/api/v1/fill", content=b"\x00" * 100, headers=garbage).status_code == 400
    r = client.post("/api/v1/fill", files=files(upload) + [("extra", ("e.png", b"1"))])
    assert r.status_code == 400 and "unknown form field 'extra'" in r.json()["detail"]
    r = client.post("/api/v1/fill", files=files(upload, target=None), data={"target": "text"})
    assert r.status_code == 400 and "'target' must be a file" in r.json()["detail"]
    r = client.post("/api/v1/fill", files=files(upload), headers={"content-length": str(10**12)})
    assert r.status_code == 413
    assert client.put("/api/v1/fill").status_code == 405


@pytest.mark.parametrize("job_id", ["nope", "../../etc/passwd", "..%2F..%2Fetc", "A" * 32, "%00", "a" * 5000])
def test_unknown_or_path_like_job_ids_are_404(idle, job_id):
    client, _, _ = idle
    for suffix in ("", "/result", "/coverage"):
        assert client.get(f"/api/v1/jobs/{job_id}{suffix}").status_code == 404
    assert client.delete(f"/api/v1/jobs/{job_id}").status_code == 404


def test_no_request_names_a_server_file_or_starts_a_download(idle, upload):
    """Every key that reads a file on the server or downloads during a fill is locked, so a new
    such key cannot slip through unlocked."""
    client, _, _ = idle
    risky = [f.key for f in config_fields() if f.key.endswith(("_model", "_path", ".download"))]
    assert {"matching.learned_model", "matching.download", "depth.model_path"} <= set(risky)
    assert set(risky) <= locked_keys()
    r = client.post("/api/v1/fill", files=files(upload), data={"config": '{"matching": {"download": true}}'})
    assert r.status_code == 422 and "matching.download" in r.json()["detail"]


def test_config_endpoints_and_docs_come_from_fillconfig(idle):
    client, _, _ = idle
    cfg = client.get("/api/v1/config").json()
    assert cfg["depth"]["backend"] == "auto" and cfg["max_pixels"] == 200_000  # the server's limit
    fields = {f["key"]: f for f in client.get("/api/v1/config/fields").json()["fields"]}
    assert len(fields) == len(config_fields())
    backend = fields["depth.backend"]
    assert backend["kind"] == "choice" and "stereo" in backend["choices"]
    assert backend["description"].startswith("``auto``: ``fused`` when the learned model's weights resolve")
    assert fields["depth.model_path"]["locked"] and not fields["depth.backend"]["locked"]
    assert fields["intrinsics.focal_px"]["optional"] and fields["intrinsics.focal_px"]["kind"] == "float"
    schema = client.get("/openapi.json").json()
    depth = schema["components"]["schemas"]["DepthConfig"]["properties"]["backend"]
    assert depth["description"] == backend["description"]
    assert "/api/v1/fill" in schema["paths"] and "/api/v1/jobs/{job_id}/coverage" in schema["paths"]
    docs = client.get("/docs")
    assert docs.status_code == 200 and "cdn" not in docs.text.lower()
    limits = client.get("/api/v1/limits").json()
    assert limits["max_sources"] == 3 and "match" in limits["stages"]


def test_page_fields_carry_bounds_sections_and_the_common_keys(idle):
    """Each number's allowed range (a list's: its items' and its length) as the config declares it,
    the sections in the pipeline's order with their descriptions, and the keys a form offers first."""
    from geofill.config import FillConfig, GeometryConfig

    client, _, _ = idle
    body = client.get("/api/v1/config/fields").json()
    fields = {f["key"]: f for f in body["fields"]}
    closed = {"lo_open": False, "hi_open": False}
    assert fields["matching.ratio"]["range"] == {"lo": 0, "hi": 1, **closed}
    assert fields["working_max_side"]["range"] == {"lo": 64, "hi": 16384, **closed}
    assert fields["intrinsics.focal_px"]["range"] == {"lo": 0, "hi": 1e6, "lo_open": True, "hi_open": False}
    target = fields["intrinsics.target"]
    assert target["length"] == [4, 4] and target["range"]["lo_open"] and target["range"]["lo"] == 0
    assert fields["optimize.edge_blur_kernels"]["range"] == {"lo": 1, "hi": 255, **closed}
    assert fields["depth.backend"]["range"] is None and fields["depth.backend"]["length"] is None
    numbers = [k for k, f in fields.items() if f["kind"] in ("int", "float")]
    assert len(numbers) > 80 and all(fields[k]["range"] for k in numbers)  # every number is bounded
    hints = typing.get_type_hints(FillConfig)
    sections = [f.name for f in dataclasses.fields(FillConfig) if dataclasses.is_dataclass(hints[f.name])]
    assert [s["key"] for s in body["sections"]] == sections
    geometry = next(s for s in body["sections"] if s["key"] == "geometry")
    assert geometry["description"] == GeometryConfig.__doc__.strip()
    assert 4 <= len(body["common"]) <= 8
    assert all(k in fields and not fields[k]["locked"] for k in body["common"])


def test_page_and_its_files_are_served_without_external_references(idle):
    client, _, _ = idle
    page = client.get("/")
    assert page.status_code == 200 and "default-src 'self'" in page.headers["content-security-policy"]
    assert client.get("/static/favicon.svg").status_code == 200
    for name in ("app.js", "style.css"):
        r = client.get(f"/static/{name}")
        assert r.status_code == 200
        assert "http://" not in r.text and "https://" not in r.text
    assert "https://" not in page.text and "http://" not in page.text


def _help(section: type, name: str) -> str:
    return next(f for f in dataclasses.fields(section) if f.name == name).metadata["help"]


def test_page_fields_and_openapi_show_each_fields_metadata(idle):
    """Every description the page and the OpenAPI schema show is the field's ``metadata["help"]``,
    and a choice field offers its Literal's values."""
    from geofill.config import DepthConfig, FillConfig, MatchingConfig, OptimizeConfig, choices

    client, _, _ = idle
    fields = {f["key"]: f for f in client.get("/api/v1/config/fields").json()["fields"]}
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    ratio = schemas["MatchingConfig"]["properties"]["ratio"]["description"]
    assert ratio == _help(MatchingConfig, "ratio") == "Lowe's ratio test threshold."
    hints = typing.get_type_hints(FillConfig)
    for key, row in fields.items():
        section, _, name = key.rpartition(".")
        cls = hints[section] if section else FillConfig
        assert row["description"] == _help(cls, name) != "", key
        assert schemas[cls.__name__]["properties"][name]["description"] == row["description"], key
    assert schemas["DepthConfig"]["description"] == DepthConfig.__doc__
    # one text shared by the fields it describes together
    weights = {fields[f"optimize.lambda_{k}"]["description"] for k in ("photo", "feat", "negd")}
    assert weights == {_help(OptimizeConfig, "lambda_feat")}
    assert fields["depth.backend"]["choices"] == list(choices(DepthConfig, "backend"))
    assert fields["depth.file_kind"]["choices"] == list(choices(DepthConfig, "file_kind"))


def test_descriptions_need_no_source_files(tmp_path):
    """An install with compiled modules only (no config.py to read) still describes every field."""
    import geofill

    copy = tmp_path / "geofill"
    shutil.copytree(Path(geofill.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert compileall.compile_dir(copy, quiet=1, legacy=True)
    for source in copy.rglob("*.py"):
        source.unlink()
    code = (
        "import geofill; from geofill.server.schema import config_fields, config_model\n"
        "assert all(f.description for f in config_fields())\n"
        "props = config_model().model_json_schema()['$defs']['MatchingConfig']['properties']\n"
        "print(geofill.__file__); print(props['ratio']['description'])"
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [str(copy / "__init__.pyc"), "Lowe's ratio test threshold."]


def test_flatten_accepts_nested_and_dotted_keys():
    assert flatten(
        {"depth": {"backend": "stereo"}, "render.edge_threshold": 0.1, "working_max_side": 640}
    ) == {
        "depth.backend": "stereo",
        "render.edge_threshold": 0.1,
        "working_max_side": 640,
    }
    assert flatten({"optimize": {"edge_blur_kernels": [3, 5]}}) == {"optimize.edge_blur_kernels": [3, 5]}


def test_serve_without_the_extra_names_it(monkeypatch, capsys):
    import builtins

    from geofill.cli import main

    real_import = builtins.__import__

    def no_uvicorn(name, *args, **kwargs):
        if name == "uvicorn":
            raise ImportError("No module named 'uvicorn'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_uvicorn)
    assert main(["serve"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(
        'geofill: error: geofill serve needs the server extra: pip install "geofill[server]"'
    )
    assert len(err.splitlines()) == 1


def test_cli_module_does_not_import_the_server_or_fastapi():
    import subprocess
    import sys

    heavy = "('fastapi', 'uvicorn', 'geofill.server')"
    code = f"import sys, geofill.cli; print(sorted(m for m in sys.modules if m.startswith({heavy})))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_stop_leaves_no_temp_files_or_workers(tmp_path):
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        assert client.get("/api/v1/limits").status_code == 200
        deadline = time.monotonic() + 60
        while not app.state.jobs.worker_pids() and time.monotonic() < deadline:
            time.sleep(0.05)
        pids = app.state.jobs.worker_pids()
        assert len(pids) == 1
    assert list(tmp_path.iterdir()) == []
    assert not any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE for p in pids)


def _keep_out() -> np.ndarray:
    """A reference mask over the right of the synthetic source (where most of the hole comes from)."""
    m = np.zeros((H, W), np.uint8)
    m[:, 240:] = 255
    return m


def test_source_mask_is_never_copied(tmp_path, pair):
    """The same fill with and without ``source_mask_1``: with it, part of the hole is refused as
    masked and less of it comes from the reference."""
    base = [
        ("target", ("t.png", png(blanked(pair.target, pair.hole)))),
        ("mask", ("m.png", png(pair.hole.astype(np.uint8) * 255))),
        ("sources", ("s.png", png(pair.source))),
    ]
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        r = client.post("/api/v1/fill", files=[*base, ("source_mask_1", ("k.png", png(_keep_out())))])
        assert r.status_code == 202, r.text
        masked_id = r.json()["id"]
        folder = app.state.jobs.get(masked_id).folder
        assert sorted(p.name for p in folder.iterdir()) == ["mask", "source-1", "source-mask-1", "target"]
        plain_id = client.post("/api/v1/fill", files=base).json()["id"]
        masked, plain = wait_for(client, masked_id), wait_for(client, plain_id)
    assert masked["state"] == plain["state"] == "done"
    assert masked["source_masks"] == [1] and plain["source_masks"] == []
    assert masked["report"]["refused_fraction"]["masked"] > 0.2
    assert plain["report"]["refused_fraction"].get("masked", 0.0) == 0.0
    assert masked["report"]["supplied_fraction"][0] < plain["report"]["supplied_fraction"][0] - 0.2
    assert "% of the hole was not copied because it was masked in the references" in masked["summary"]
    assert "masked" not in plain["summary"]


@pytest.mark.parametrize(
    ("parts", "words"),
    [
        (
            [("source_mask_1", "small")],
            "source_mask_1: reference mask is 100x100 but its reference sources[1] is 320x240",
        ),
        (
            [("source_mask_2", "keep_out")],
            "source_mask_2: a mask for sources[2], but 1 reference photo(s) given",
        ),
        ([("source_mask_1", "keep_out")] * 2, "the form field 'source_mask_1' is given twice"),
        (
            [("source_mask_4", "keep_out")],
            "unknown form field 'source_mask_4' "
            "(expected target, mask, sources, source_mask_1 ... source_mask_3, config)",
        ),
        ([("source_mask_0", "keep_out")], "unknown form field 'source_mask_0'"),
        ([("source_mask_1", "corrupt")], "source_mask_1: not a PNG, JPEG, WebP, TIFF or HEIC image"),
    ],
)
def test_bad_source_masks_are_400_naming_the_field(idle, upload, parts, words):
    client, app, _ = idle
    data = {
        "small": png(np.full((100, 100), 255, np.uint8)),
        "keep_out": png(_keep_out()),
        "corrupt": b"nope",
    }
    r = client.post("/api/v1/fill", files=files(upload) + [(name, ("k.png", data[k])) for name, k in parts])
    assert r.status_code == 400, r.text
    assert r.json()["detail"] == words or words in r.json()["detail"]
    assert app.state.jobs.counts() == {}
    assert list(app.state.jobs.root.iterdir()) == []


def test_source_mask_as_text_is_refused_and_openapi_lists_one_per_source(idle, upload):
    client, _, _ = idle
    r = client.post("/api/v1/fill", files=files(upload), data={"source_mask_1": "text"})
    assert r.status_code == 400 and "'source_mask_1' must be a file" in r.json()["detail"]
    form = client.get("/openapi.json").json()["paths"]["/api/v1/fill"]["post"]["requestBody"]
    props = form["content"]["multipart/form-data"]["schema"]["properties"]
    assert [k for k in props if k.startswith("source_mask_")] == [
        "source_mask_1",
        "source_mask_2",
        "source_mask_3",
    ]
    assert props["source_mask_2"]["format"] == "binary"
    assert props["source_mask_2"]["description"].startswith("optional mask of sources[2]")
    assert "never copied" in props["source_mask_2"]["description"]
