"""What one request to ``geofill serve`` may cost: every setting that scales a fill's time or memory
is capped by the server (a request may lower it, never raise it), a queue place is held before any
upload is stored or decoded, finished jobs keep only their results under a disk cap, and every key
that names a file on the server or lets a fill download is locked by its type."""

from __future__ import annotations

import dataclasses
import json
import re
import sys
import threading
import time
import typing
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi", reason="the server extra is not installed")
pytest.importorskip("httpx", reason="FastAPI's TestClient needs httpx")
from fastapi.testclient import TestClient

from geofill.cli import main
from geofill.config import COSTLY, DownloadSwitch, FillConfig, LocalPath, Range, setting
from geofill.errors import ConfigError
from geofill.server import app as app_module
from geofill.server.app import create_app
from geofill.server.jobs import ServerSettings
from geofill.synthetic import make_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/: the repository's package
# OVER_COST: the request of the report, each of whose keys was accepted (202) and could hold a
# worker for days.
from benchmarks.speed.server_bench import OVER_COST, png


@pytest.fixture(scope="module")
def parts():
    """A small synthetic pair as multipart files."""
    pair = make_pair(seed=1, width=160, height=120)
    return [
        ("target", ("t.png", png(pair.target))),
        ("mask", ("m.png", png(pair.hole.astype(np.uint8) * 255))),
        ("sources", ("s.png", png(pair.source))),
    ]


def idle_client(tmp_path: Path, **settings) -> TestClient:
    """A server with no worker (jobs stay queued), as a context manager."""
    defaults = {"workers": 0, "queue_size": 4, "temp_parent": str(tmp_path)}
    return TestClient(create_app(ServerSettings(**(defaults | settings))))


@pytest.mark.parametrize(("key", "value"), OVER_COST.items())
def test_over_cost_config_is_422_naming_the_key_and_the_cap(tmp_path, parts, key, value):
    default = FillConfig().to_dict()
    for part in key.split("."):
        default = default[part]
    with idle_client(tmp_path) as client:
        r = client.post("/api/v1/fill", files=parts, data={"config": json.dumps({key: value})})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert f"'{key}'" in detail and f"cap of {default:g}" in detail, detail
        # the same key lowered is accepted, and the whole over-cost request of the report is refused
        lower = default / 2 if isinstance(default, float) else max(default // 2, 1)
        r = client.post("/api/v1/fill", files=parts, data={"config": json.dumps({key: lower})})
        assert r.status_code == 202, r.text
        r = client.post("/api/v1/fill", files=parts, data={"config": json.dumps(OVER_COST)})
        assert r.status_code == 422


def test_zero_meaning_no_limit_and_list_items_are_capped(tmp_path, parts):
    with idle_client(tmp_path) as client:
        r = client.post("/api/v1/fill", files=parts, data={"config": '{"matching.max_features": 0}'})
        assert r.status_code == 422 and "0 (no limit) is over this server's cap of 4000" in r.json()["detail"]
        many = json.dumps({"optimize.fast_iterations": [30, 20, 12, 31]})
        r = client.post("/api/v1/fill", files=parts, data={"config": many})
        assert r.status_code == 422 and "cap of 30" in r.json()["detail"]


def test_operator_caps_raise_and_lower_what_a_request_may_cost(tmp_path, parts):
    caps = {"working_max_side": 2048, "time_budget_s": 600, "matching.max_features": 0}
    with idle_client(tmp_path, caps=caps) as client:
        # a lower cap lowers the server's default too; a cap of 0 on a zero-is-no-limit key allows all
        assert client.get("/api/v1/config").json()["time_budget_s"] == 600
        limits = client.get("/api/v1/limits").json()
        assert limits["caps"]["working_max_side"] == 2048 and limits["caps"]["fusion.parallel"] == 2
        ok = {"working_max_side": 2048, "matching.max_features": 0, "time_budget_s": 600}
        r = client.post("/api/v1/fill", files=parts, data={"config": json.dumps(ok)})
        assert r.status_code == 202, r.text
        r = client.post("/api/v1/fill", files=parts, data={"config": '{"working_max_side": 2049}'})
        assert r.status_code == 422 and "cap of 2048" in r.json()["detail"]
        fields = {f["key"]: f for f in client.get("/api/v1/config/fields").json()["fields"]}
        assert fields["working_max_side"]["cap"] == 2048 and fields["matching.ratio"]["cap"] is None
        assert fields["matching.learned_threads"]["zero_is_most"]
    with pytest.raises(ConfigError, match=r"--cap matching\.ratio: not a setting that scales"):
        create_app(ServerSettings(workers=0, caps={"matching.ratio": 1.0}))
    with pytest.raises(ConfigError, match=r"--cap working_max_side: expected a whole number"):
        create_app(ServerSettings(workers=0, caps={"working_max_side": 1000.5}))


#: Words in a numeric field's name that say it scales the work: a new such field must be a cost.
COST_WORDS = re.compile(
    r"max_side|features|keypoints|max_matches|iters|iterations|threads|parallel|levels|planes|steps|"
    r"resamples|tilt|budget|best_k"
)


def test_every_cost_setting_of_the_schema_is_capped(tmp_path):
    """Walks the whole config: every numeric field named like a cost is marked as one, and every
    cost has a cap the page and the API show."""
    from geofill.server.schema import config_fields

    numeric = [f for f in config_fields() if f.kind in ("int", "float", "list") and not f.locked]
    leaf = {f.key: f.key.rsplit(".", 1)[-1] for f in numeric}
    # "min_..." is a threshold (optimize.min_features: fewer features skip the stage), not work
    named = {k for k, name in leaf.items() if COST_WORDS.search(name) and not name.startswith("min_")}
    costly = {f.key for f in config_fields() if f.cost}
    assert named - costly == set(), "numeric settings named like a cost but not marked Cost"
    assert {"optimize.threads", "fusion.parallel", "time_budget_s", "optimize.paper_iterations"} <= costly
    with idle_client(tmp_path) as client:
        caps = client.get("/api/v1/limits").json()["caps"]
        assert set(caps) == costly
        fields = {f["key"]: f for f in client.get("/api/v1/config/fields").json()["fields"]}
        assert {k for k, f in fields.items() if f["cap"] is not None} == costly


def test_every_path_file_model_and_download_field_is_locked(tmp_path, parts):
    """Walks the whole config: a field that can hold free text (a path, a model name) or whose name
    says it names a file or downloads is locked, and a request setting it is a 422."""
    from geofill.server.schema import config_fields, locked_keys

    hints: dict[str, typing.Any] = {}

    def walk(cls: type, prefix: str) -> None:
        for f in dataclasses.fields(cls):
            tp = typing.get_type_hints(cls)[f.name]
            if dataclasses.is_dataclass(tp):
                walk(tp, f"{prefix}{f.name}.")
            else:
                hints[f"{prefix}{f.name}"] = tp

    walk(FillConfig, "")
    text = {k for k, tp in hints.items() if {str, Path} & {tp, *typing.get_args(tp)}}
    named = {k for k in hints if re.search(r"(path|file|dir|model|url|download)$", k)}
    named -= {"depth.model"}  # a choice among the known networks, not a file
    assert {"depth.file_path", "depth.model_path", "inpaint.lama_model", "matching.download"} <= text | named
    assert (text | named) - locked_keys() == set()
    fields = {f.key: f for f in config_fields()}
    with idle_client(tmp_path) as client:
        for key in sorted(locked_keys()):
            value = True if fields[key].kind == "bool" else "/etc/passwd" if fields[key].kind == "str" else 1
            r = client.post("/api/v1/fill", files=parts, data={"config": json.dumps({key: value})})
            assert r.status_code == 422 and f"'{key}'" in r.json()["detail"], (key, r.text)


def test_a_new_path_or_cost_field_is_locked_or_capped_by_its_type_alone():
    """A config that nobody listed anywhere: its path, download switch and free text are locked,
    its costly count is a cost, the rest is neither."""
    from geofill.server.schema import config_fields

    @dataclasses.dataclass
    class Later:
        weights: LocalPath | None = setting(None, "a file")
        fetch: DownloadSwitch = setting(False, "download it")
        label: str = setting("x", "free text")
        rounds: typing.Annotated[int, Range(1, 100), COSTLY] = setting(3, "more is slower")
        ratio: typing.Annotated[float, Range(0, 1)] = setting(0.5, "a threshold")
        mode: typing.Literal["a", "b"] = setting("a", "a choice")

    fields = {f.key: f for f in config_fields(Later)}
    assert {k for k, f in fields.items() if f.locked} == {"weights", "fetch", "label"}
    assert {k for k, f in fields.items() if f.cost} == {"rounds"}


def test_a_queue_place_is_held_before_any_upload_is_decoded(tmp_path, parts, monkeypatch):
    """Three requests at once on a one-place queue: one is read and decoded, the others are 429
    before their images are touched; any refusal gives its place back."""
    decoding = threading.Semaphore(0)
    release = threading.Event()
    inside, most = [0], [0]
    real = app_module._validate_inputs

    def slow_validate(*args, **kwargs):
        inside[0] += 1
        most[0] = max(most[0], inside[0])
        decoding.release()
        release.wait(10)
        try:
            return real(*args, **kwargs)
        finally:
            inside[0] -= 1

    monkeypatch.setattr(app_module, "_validate_inputs", slow_validate)
    with idle_client(tmp_path, queue_size=1) as client:
        with ThreadPoolExecutor(3) as pool:
            first = pool.submit(client.post, "/api/v1/fill", files=parts)
            assert decoding.acquire(timeout=10)  # the first request is decoding its images
            others = [pool.submit(client.post, "/api/v1/fill", files=parts) for _ in range(2)]
            statuses = [f.result(timeout=30).status_code for f in others]
            release.set()
            assert first.result(timeout=30).status_code == 202
        assert statuses == [429, 429] and most[0] == 1
        job = client.get("/api/v1/limits")  # the server still answers
        assert job.status_code == 200
    # refusals give their place back: a queue of one takes a good request after bad ones
    monkeypatch.setattr(app_module, "_validate_inputs", real)
    with idle_client(tmp_path, queue_size=1) as client:
        bad = [("target", ("t.png", b"not an image")), *parts[1:]]
        for _ in range(3):
            assert client.post("/api/v1/fill", files=bad).status_code == 400
            assert client.post("/api/v1/fill", files=parts, data={"config": "{"}).status_code == 422
        assert client.post("/api/v1/fill", files=parts).status_code == 202
        assert client.post("/api/v1/fill", files=parts).status_code == 429


def wait_done(client: TestClient, job_id: str, timeout_s: float = 300.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        snap = client.get(f"/api/v1/jobs/{job_id}").json()
        if snap["state"] not in ("queued", "running"):
            return snap
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} still {snap['state']} after {timeout_s} s")


def test_finished_jobs_keep_only_results_and_the_oldest_are_evicted_over_the_disk_cap(tmp_path, parts):
    fast = json.dumps({"optimize.enabled": False, "matching.max_rung": "sift", "inpaint.method": "telea"})
    app = create_app(ServerSettings(workers=1, temp_parent=str(tmp_path)))
    with TestClient(app) as client:
        jobs = app.state.jobs
        first = client.post("/api/v1/fill", files=parts, data={"config": fast}).json()["id"]
        assert wait_done(client, first)["state"] == "done"
        # the uploads are deleted when the job ends: only what the client may download stays
        assert sorted(p.name for p in jobs.get(first).folder.iterdir()) == ["coverage.png", "result.png"]
        kept = jobs.disk_bytes()
        assert 0 < kept < 200_000
        # a cap just under the first job's files plus the next one's uploads: they push it out
        uploads = sum(len(data) for _, (_, data) in parts)
        cap = max(kept, uploads) + min(kept, uploads) - 1
        jobs.settings = dataclasses.replace(jobs.settings, disk_cap_bytes=cap)
        second = client.post("/api/v1/fill", files=parts, data={"config": fast}).json()["id"]
        snap = client.get(f"/api/v1/jobs/{first}").json()
        assert snap["state"] == "done" and "disk cap" in snap["evicted"]
        r = client.get(f"/api/v1/jobs/{first}/result")
        assert r.status_code == 410 and "disk cap" in r.json()["detail"]
        assert not jobs.get(first).folder.exists()
        assert wait_done(client, second)["state"] == "done" and jobs.disk_bytes() <= cap
        assert client.get(f"/api/v1/jobs/{second}/result").status_code == 200
        assert client.get(f"/api/v1/jobs/{second}").json()["evicted"] is None
        # nothing finished left to evict and the cap below one upload: a new request is a 429
        jobs.settings = dataclasses.replace(jobs.settings, disk_cap_bytes=1000)
        r = client.post("/api/v1/fill", files=parts, data={"config": fast})
        assert r.status_code == 429 and "disk" in r.json()["detail"], r.text
        assert client.get(f"/api/v1/jobs/{second}/result").status_code == 410


def test_serve_help_and_errors_name_the_caps(capsys):
    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--cap KEY=VALUE" in text and "--disk-cap-mb" in text
    assert "working_max_side" in text and "optimize.threads" in text and "fusion.parallel" in text
    code = main(["serve", "--cap", "matching.ratio=0.5", "--port", "1"])
    err = capsys.readouterr().err
    assert code != 0 and "--cap matching.ratio: not a setting that scales" in err
