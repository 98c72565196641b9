"""``geofill serve`` under load, over loopback HTTP against a real server process: 50 requests at
once, good small fills mixed with malformed and truncated images, wrong-size masks, configs over
the server's caps and bad JSON. No answer is a 5xx, each request gets its own status or the queue's
429, and the server process's memory stays flat. Bounded: two bursts of 50, the accepted jobs
cancelled after each, the server stopped at the end (about 20 s here).

The load itself is ``benchmarks/speed/server_bench.py``'s (``--load``), which prints the same run's
figures."""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import pytest

pytest.importorskip("fastapi", reason="the server extra is not installed")
pytest.importorskip("httpx", reason="the load client needs httpx")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # benchmarks/ is a package of the repository, not of geofill
from benchmarks.speed.server_bench import Server, load_burst, load_kinds  # noqa: E402

BURST = 50
#: Growth (MiB) of the server process's RSS over one burst once warm: the allocator's arenas for
#: the request threads settle after the first burst (+7 MiB, then +0.1 to +1.4 in
#: server_bench.py's rounds); 50 decoded 640x480 uploads kept would be about 130 MiB.
MAX_GROWTH_MB = 16.0


@pytest.fixture
def server(tmp_path):
    s = Server(tmp_path)
    yield s
    s.stop()


def test_fifty_mixed_requests_at_once_no_5xx_flat_memory_and_429(server):
    kinds = load_kinds()
    warm = load_burst(server, BURST)  # the first burst: the request threads' memory is set up
    out = load_burst(server, BURST)
    statuses = warm["statuses"] + out["statuses"]
    by_status = Counter(status for (_, status) in statuses.elements())
    assert not [s for s in by_status if s >= 500], by_status
    for (kind, status), n in statuses.items():
        assert status in (kinds[kind][2], 429), (kind, status, n)
    assert by_status[429] > 0  # the queue limit is answered, not queued without bound
    assert by_status[202] >= 1 and by_status[400] + by_status[422] >= 1  # the server did work too
    growth = out["rss_after_mb"] - out["rss_before_mb"]
    assert growth < MAX_GROWTH_MB, out
    assert server.client.get("/api/v1/limits").status_code == 200
