"""``geofill serve`` measured over real HTTP against a ``geofill serve`` process:

1. Fill -> result time for a 1280x720 synthetic pair through the API (POST, poll, download) against
   the CLI's pipeline time for the same fill (``geofill fill --debug-dir``: report.json's stage
   times) and the CLI's whole run, interleaved (server, CLI, server, CLI, ...) because the machine is
   shared;
2. the server's RSS (server process + its worker processes) idle and during a fill;
3. ``--fills`` sequential API fills (640x480), each job deleted after its download as a client
   does: RSS and the number of files in the server's folder after each;
4. ``--malformed`` malformed requests (bad multipart, wrong types, huge headers, unknown and
   path-like job ids, a client that disconnects mid-upload): how many answers are >= 500;
5. ``--load`` requests at once, good and bad mixed (:func:`load_kinds`: good small fills, malformed
   and truncated images, wrong-size masks, configs over the server's caps, bad JSON), on a
   ``--queue 4`` server, ``--load-rounds`` times: the statuses by kind, the server process's peak
   RSS and its RSS before and after each round (the accepted jobs then cancelled), the wall time.

Run: ``.venv/bin/python benchmarks/speed/server_bench.py [--repeats 3] [--fills 20] [--malformed 200]
[--load 50] [--load-rounds 3]``; ``--only-load`` runs section 5 alone.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import psutil
from PIL import Image

from geofill.synthetic import make_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import timed_child

GEOFILL = str(Path(sys.executable).with_name("geofill"))


def png(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, "PNG")
    return buf.getvalue()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def tree_rss_mb(proc: psutil.Process) -> float:
    total = 0
    for p in [proc, *proc.children(recursive=True)]:
        try:
            total += p.memory_info().rss
        except psutil.NoSuchProcess:
            pass
    return total / 2**20


class Server:
    """A ``geofill serve`` subprocess with its own TMPDIR (so its folder can be watched); ``flags``
    are more of ``geofill serve``'s."""

    def __init__(self, tmp: Path, flags: tuple[str, ...] = ()) -> None:
        self.tmp = tmp
        self.port = free_port()
        env = dict(os.environ, TMPDIR=str(tmp), HF_HUB_OFFLINE="1")
        cmd = [GEOFILL, "serve", "--port", str(self.port), "--workers", "1", "--queue", "4", *flags]
        self.proc = subprocess.Popen(cmd, env=env, stderr=subprocess.DEVNULL)
        self.ps = psutil.Process(self.proc.pid)
        self.url = f"http://127.0.0.1:{self.port}"
        self.client = httpx.Client(base_url=self.url, timeout=600)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if self.client.get("/api/v1/limits").status_code == 200 and len(self.ps.children()) >= 1:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        time.sleep(5)  # the worker imports the pipeline after it starts

    def files(self) -> int:
        return sum(1 for p in self.tmp.rglob("*") if p.is_file())

    def fill(self, parts: list, sampler: list[float] | None = None) -> tuple[float, dict]:
        """POST, poll, download; (seconds from POST to downloaded result, job snapshot)."""
        t0 = time.perf_counter()
        job = self.client.post("/api/v1/fill", files=parts).json()["id"]
        polls = 0
        while True:
            snap = self.client.get(f"/api/v1/jobs/{job}").json()
            if sampler is not None and polls % 3 == 0:
                sampler.append(tree_rss_mb(self.ps))
            if snap["state"] not in ("queued", "running"):
                break
            polls += 1
            time.sleep(0.3)  # as the page polls
        assert snap["state"] == "done", snap
        result = self.client.get(f"/api/v1/jobs/{job}/result")
        assert result.status_code == 200
        dt = time.perf_counter() - t0
        self.client.delete(f"/api/v1/jobs/{job}")
        return dt, snap

    def stop(self) -> None:
        self.client.close()
        self.proc.terminate()
        self.proc.wait(30)


def scene_parts(width: int, height: int, seed: int = 0) -> tuple[list, dict[str, bytes]]:
    pair = make_pair(seed=seed, width=width, height=height)
    data = {
        "target": png(pair.target),
        "mask": png(pair.hole.astype(np.uint8) * 255),
        "source": png(pair.source),
    }
    parts = [
        ("target", ("t.png", data["target"])),
        ("mask", ("m.png", data["mask"])),
        ("sources", ("s.png", data["source"])),
    ]
    return parts, data


def cli_fill(data: dict[str, bytes], work: Path) -> tuple[float, float]:
    """(pipeline seconds from report.json, whole CLI run seconds) of ``geofill fill``."""
    for name, blob in data.items():
        (work / f"{name}.png").write_bytes(blob)
    debug = work / "debug"
    wall, _ = timed_child(
        [GEOFILL, "fill", "--target", str(work / "target.png"), "--mask", str(work / "mask.png"),
         "--source", str(work / "source.png"), "-o", str(work / "out.png"), "--debug-dir", str(debug), "-q"],
        env=dict(os.environ, HF_HUB_OFFLINE="1"),
    )  # fmt: skip
    report = json.loads((debug / "report.json").read_text())
    return sum(report["timings_s"].values()), wall


def overhead(server: Server, repeats: int, work: Path) -> None:
    parts, data = scene_parts(1280, 720)
    print("\n## 1280x720 fill: API (POST -> result downloaded) vs CLI, interleaved")
    rows = []
    idle = tree_rss_mb(server.ps)
    peak: list[float] = []
    first_s, _ = server.fill(parts, peak)
    print(f"first fill of a fresh worker (numba cache, first-call set-up): API {first_s:.2f} s, not counted")
    for i in range(repeats):
        api_s, snap = server.fill(parts, peak)
        worker_s = sum(v for k, v in snap["timings_s"].items() if k not in ("read inputs", "write result"))
        cli_pipe, cli_wall = cli_fill(data, work)
        rows.append((api_s, worker_s, cli_pipe, cli_wall))
        print(
            f"run {i + 1}: API {api_s:.2f} s (pipeline in the worker {worker_s:.2f} s) | "
            f"CLI pipeline {cli_pipe:.2f} s, CLI run {cli_wall:.2f} s"
        )
    api, wrk, pipe, wall = (statistics.median(c) for c in zip(*rows, strict=True))
    print(
        f"median: API {api:.2f} s, CLI pipeline {pipe:.2f} s -> API / CLI pipeline = {api / pipe:.3f} "
        f"({100 * (api / pipe - 1):+.1f} %); API - worker pipeline = {api - wrk:.2f} s "
        f"({100 * (api / wrk - 1):+.1f} % of it); CLI whole run {wall:.2f} s"
    )
    print(
        f"server RSS (server + worker processes): idle {idle:.0f} MiB, "
        f"during the fills peak {max(peak):.0f} MiB"
    )


def sequential(server: Server, fills: int) -> None:
    parts, _ = scene_parts(640, 480, seed=2)
    print(f"\n## {fills} sequential API fills (640x480), each job deleted after its download")
    rss, files, times = [], [], []
    for _ in range(fills):
        dt, _snap = server.fill(parts)
        times.append(dt)
        rss.append(tree_rss_mb(server.ps))
        files.append(server.files())
    print("RSS after each fill (MiB): " + " ".join(f"{r:.0f}" for r in rss))
    print("files in the server's folder after each fill: " + " ".join(str(f) for f in files))
    print(
        f"RSS first {rss[0]:.0f} MiB, last {rss[-1]:.0f} MiB, max {max(rss):.0f} MiB; "
        f"last 10 vs first 10 median: {statistics.median(rss[-10:]) - statistics.median(rss[:10]):+.0f} MiB; "
        f"fill time median {statistics.median(times):.2f} s"
    )


def raw(port: int, payload: bytes, read: bool = True) -> int | None:
    """Send raw bytes; the HTTP status of the answer (None when the server closed without one)."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(payload)
        if not read:
            return None
        try:
            head = s.recv(64)
        except (ConnectionResetError, TimeoutError):
            return None
    return int(head.split(b" ")[1]) if head.startswith(b"HTTP/") else None


def malformed(server: Server, total: int) -> None:
    print(f"\n## {total} malformed requests")
    c = server.client
    parts, data = scene_parts(320, 240, seed=3)
    rng = np.random.default_rng(0)
    statuses: list[int | str | None] = []
    multipart = {"content-type": "multipart/form-data; boundary=x"}
    part_head = b'--x\r\nContent-Disposition: form-data; name="target"\r\n\r\n'
    big_header = b"GET /api/v1/limits HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 200_000 + b"\r\n\r\n"
    bad_length = b"POST /api/v1/fill HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n"
    cut_upload = (
        b"POST /api/v1/fill HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b'Content-Length: 100000\r\n\r\n--b\r\nContent-Disposition: form-data; name="target"; filename="t"'
        b"\r\n\r\n" + rng.bytes(5000)
    )
    bad_config = '{"depth": {"backend": 7}}'

    def disconnect(i: int) -> str:
        raw(server.port, cut_upload, read=False)
        return "client disconnected mid-upload"

    kinds = [
        lambda i: c.post("/api/v1/fill", content=rng.bytes(int(rng.integers(1, 4000))), headers=multipart),
        lambda i: c.post("/api/v1/fill", content=part_head + rng.bytes(100), headers=multipart),
        lambda i: c.post("/api/v1/fill", json={"target": i}),
        lambda i: c.post("/api/v1/fill", files=[("target", ("t", rng.bytes(500))), *parts[1:]]),
        lambda i: c.post("/api/v1/fill", files=parts, data={"config": rng.bytes(50).hex()}),
        lambda i: c.post("/api/v1/fill", files=parts, data={"config": bad_config}),
        lambda i: c.post("/api/v1/fill", files=parts[:2]),
        lambda i: c.post("/api/v1/fill", files=[("mask", ("m", data["target"])), *parts[1:]]),
        lambda i: c.get(f"/api/v1/jobs/{rng.bytes(8).hex()}"),
        lambda i: c.get("/api/v1/jobs/..%2F..%2Fetc%2Fpasswd/result"),
        lambda i: c.get("/api/v1/jobs/" + "A" * 32 + "/coverage"),
        lambda i: c.delete("/api/v1/jobs/%2e%2e%2f%2e%2e"),
        lambda i: raw(server.port, big_header),
        lambda i: raw(server.port, bad_length),
        disconnect,
    ]
    for i in range(total):
        try:
            answer = kinds[i % len(kinds)](i)
            statuses.append(answer.status_code if isinstance(answer, httpx.Response) else answer)
        except httpx.HTTPError as exc:
            statuses.append(None)
            print(f"request {i}: {type(exc).__name__}: {exc}")
        if i % 50 == 49:
            # a full queue would answer 429 to the valid-looking uploads: let it drain between bursts
            time.sleep(0.2)
    counts: dict[str, int] = {}
    for s in statuses:
        counts[str(s)] = counts.get(str(s), 0) + 1
    print("statuses: " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    print(f"responses >= 500: {sum(1 for s in statuses if isinstance(s, int) and s >= 500)} of {total}")
    time.sleep(1.0)
    uploads = list(server.tmp.rglob("upload-*"))
    print(f"unfinished upload folders left after the disconnects: {len(uploads)}")
    print(f"server still answers: {c.get('/api/v1/limits').status_code == 200}")


#: A good fill's config: the cheap path, so that a loaded server's queue moves.
FAST_CONFIG = {"optimize.enabled": False, "matching.max_rung": "sift", "inpaint.method": "telea"}
#: The over-cost request of the report that added the caps (each key was accepted before).
OVER_COST = {
    "time_budget_s": 1e6,
    "working_max_side": 16384,
    "fusion.parallel": 64,
    "optimize.threads": 256,
    "matching.max_features": 1_000_000,
}


def load_kinds(seed: int = 4) -> dict[str, tuple[list, dict[str, str], int]]:
    """Each kind of request of the load run: (files, form fields, the status it gets when the
    queue has room; 429 otherwise). Good fills are 320x240; the images a bad request sends are
    640x480, decoded before they are refused."""
    parts, data = scene_parts(320, 240, seed=seed)
    big, _ = scene_parts(640, 480, seed=seed + 1)
    rng = np.random.default_rng(seed)
    fast = {"config": json.dumps(FAST_CONFIG)}
    return {
        "good fill": (parts, fast, 202),
        "malformed image": ([("target", ("t.png", rng.bytes(20_000))), *parts[1:]], fast, 400),
        "truncated image": (
            [("target", ("t.png", data["target"][: len(data["target"]) // 2])), *parts[1:]],
            fast,
            400,
        ),
        "wrong-size mask": ([big[0], parts[1], big[2]], fast, 400),
        "over-cap config": (parts, {"config": json.dumps(OVER_COST)}, 422),
        "bad JSON config": (big, {"config": "{"}, 422),
    }


def rss_mb(proc: psutil.Process) -> float:
    return proc.memory_info().rss / 2**20


def load_burst(server: Server, total: int) -> dict:
    """``total`` requests at once (one thread each), cycling through :func:`load_kinds`; the
    accepted jobs are cancelled afterwards. Returns the statuses by kind (``Counter`` of
    (kind, status)), the job ids accepted, the server process's RSS before, at its peak during the
    burst and after the cancels (MiB), and the burst's wall time."""
    kinds = list(load_kinds().items())
    before = rss_mb(server.ps)
    peak = [before]
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.02):
            peak.append(rss_mb(server.ps))

    def send(i: int) -> tuple[str, int, str | None]:
        kind, (files, form, _) = kinds[i % len(kinds)]
        r = server.client.post("/api/v1/fill", files=files, data=form)
        return kind, r.status_code, r.json().get("id") if r.status_code == 202 else None

    sampler = threading.Thread(target=sample)
    sampler.start()
    t0 = time.perf_counter()
    try:
        with ThreadPoolExecutor(total) as pool:
            answers = list(pool.map(send, range(total)))
    finally:
        wall = time.perf_counter() - t0
        done.set()
        sampler.join()
    accepted = [job for _, _, job in answers if job]
    for job in accepted:
        server.client.delete(f"/api/v1/jobs/{job}")
    return {
        "statuses": Counter((kind, status) for kind, status, _ in answers),
        "accepted": accepted,
        "rss_before_mb": before,
        "rss_peak_mb": max(peak),
        "rss_after_mb": rss_mb(server.ps),
        "wall_s": wall,
    }


def load(server: Server, total: int, rounds: int) -> None:
    print(f"\n## {rounds} rounds of {total} requests at once, good and bad mixed (--workers 1 --queue 4)")
    load_burst(server, len(load_kinds()))  # one of each: the server's first decodes and imports
    for i in range(rounds):
        out = load_burst(server, total)
        by_status = Counter(status for (_, status) in out["statuses"].elements())
        print(
            f"round {i + 1}: {total} requests in {out['wall_s']:.2f} s; statuses: "
            + ", ".join(f"{k}: {v}" for k, v in sorted(by_status.items()))
            + f"; responses >= 500: {sum(v for k, v in by_status.items() if k >= 500)}"
        )
        for kind, (_, _, expected) in load_kinds().items():
            row = {status: n for (k, status), n in out["statuses"].items() if k == kind}
            print(
                f"  {kind} (expected {expected} or 429): "
                + ", ".join(f"{k}: {v}" for k, v in sorted(row.items()))
            )
        before, peak, after = out["rss_before_mb"], out["rss_peak_mb"], out["rss_after_mb"]
        print(
            f"  server process RSS: before {before:.1f} MiB, peak {peak:.1f} MiB, after (accepted jobs "
            f"cancelled) {after:.1f} MiB ({after - before:+.1f}); "
            f"server + workers now {tree_rss_mb(server.ps):.0f} MiB"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fills", type=int, default=20)
    ap.add_argument("--malformed", type=int, default=200)
    ap.add_argument("--load", type=int, default=50)
    ap.add_argument("--load-rounds", type=int, default=3)
    ap.add_argument("--only-load", action="store_true", help="section 5 alone")
    args = ap.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} (shared with other jobs)")
    tmp = Path(tempfile.mkdtemp(prefix="geofill-server-bench-"))
    (tmp / "server-tmp").mkdir()
    server = Server(tmp / "server-tmp")
    work = tmp / "cli"
    work.mkdir()
    try:
        if not args.only_load:
            overhead(server, args.repeats, work)
            if args.fills:
                sequential(server, args.fills)
            if args.malformed:
                malformed(server, args.malformed)
        if args.load:
            load(server, args.load, args.load_rounds)
    finally:
        server.stop()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
