"""``geofill batch --ray``: a local Ray instance with 2 CPUs gives the outputs of ``--jobs 2``, and a
worker process killed mid-batch loses and duplicates nothing (Ray runs its task again).

Skipped when Ray is not installed (extra ``geofill[ray]``)."""

from __future__ import annotations

import json
import os
import signal
import threading
import time

import cv2
import numpy as np
import psutil
import pytest

from geofill.cli import main
from geofill.synthetic import make_pair

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'geofill[ray]')")

TASK_TITLE = "ray::run_item_on_ray"  # Ray's process title of a worker running a batch item


@pytest.fixture(scope="module")
def shoot(tmp_path_factory):
    root = tmp_path_factory.mktemp("shoot")
    for d in ("images", "masks"):
        (root / d).mkdir()
    pairs = {}
    for seed in (3, 5):
        name, p = f"t{seed}", make_pair(seed=seed, width=320, height=240)
        (root / "refs" / name).mkdir(parents=True)
        cv2.imwrite(str(root / "images" / f"{name}.png"), p.target[..., ::-1])
        cv2.imwrite(str(root / "refs" / name / "view.png"), p.source[..., ::-1])
        cv2.imwrite(str(root / "masks" / f"{name}.png"), p.hole.astype(np.uint8) * 255)
        pairs[name] = p
    local = root / "out_jobs2"
    assert _batch(root, local, "--jobs", "2") == 0
    return root, pairs, _records(local), local


def _batch(root, out, *extra):
    argv = ["batch", "--images", root / "images", "--masks", root / "masks"]
    argv += ["--sources-per-image", root / "refs", "--out", out, "-q", *extra]
    return main([str(a) for a in argv])


def _records(out):
    return {r["item"]: r for r in map(json.loads, (out / "results.jsonl").read_text().splitlines())}


def _assert_same_outputs(out, local, pairs, records, local_records):
    """Same items, statuses, references and coverage, and byte-identical images: a Ray worker and
    a spawned worker are both single-threaded and every stage is deterministic."""
    assert set(records) == set(local_records) == set(pairs)
    for name, r in records.items():
        mine = local_records[name]
        assert r["status"] == mine["status"] == "reference"
        assert r["references"] == mine["references"]
        assert r["coverage"] == mine["coverage"]
        a = cv2.imread(str(out / f"{name}.png"))
        b = cv2.imread(str(local / f"{name}.png"))
        np.testing.assert_array_equal(a, b)


def test_ray_local_instance_matches_jobs_2(shoot, tmp_path):
    root, pairs, local_records, local = shoot
    out = tmp_path / "ray"
    assert _batch(root, out, "--ray", "local", "--jobs", "2") == 0
    records = _records(out)
    _assert_same_outputs(out, local, pairs, records, local_records)
    assert all(r["worker"]["pid"] != os.getpid() for r in records.values())


def test_ray_worker_killed_mid_batch_loses_and_duplicates_nothing(shoot, tmp_path):
    root, pairs, local_records, local = shoot
    killed: list[int] = []
    stop = threading.Event()

    def kill_one_running_task():
        while not stop.is_set() and not killed:
            for proc in psutil.process_iter(["pid", "cmdline"]):
                if TASK_TITLE in " ".join(proc.info["cmdline"] or []):
                    time.sleep(1.0)  # well into the fill
                    os.kill(proc.info["pid"], signal.SIGKILL)
                    killed.append(proc.info["pid"])
                    break
            time.sleep(0.1)

    killer = threading.Thread(target=kill_one_running_task, daemon=True)
    killer.start()
    out = tmp_path / "ray_killed"
    try:
        code = _batch(root, out, "--ray", "local", "--jobs", "2")
    finally:
        stop.set()
        killer.join()
    assert len(killed) == 1
    assert code == 0
    lines = (out / "results.jsonl").read_text().splitlines()
    records = _records(out)
    assert len(lines) == len(records) == 2  # one line per item, none twice
    assert killed[0] not in {r["worker"]["pid"] for r in records.values()}  # its item ran again elsewhere
    _assert_same_outputs(out, local, pairs, records, local_records)
    assert sorted(f.name for f in out.iterdir()) == ["results.jsonl", "t3.png", "t5.png"]
