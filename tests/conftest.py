"""Shared fixtures: real pairs from ../shared (skipped when absent)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# No test may reach the network, the user's weight caches or their explicit model paths: `auto`
# depth must see "no weights" unless a test provides them (download tests start a local server).
os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["GEOFILL_CACHE"] = tempfile.mkdtemp(prefix="geofill-test-cache-")
os.environ["HF_HUB_CACHE"] = os.environ["GEOFILL_CACHE"]
for _var in (
    "GEOFILL_DEPTH_ANYTHING_V2_SMALL",
    "GEOFILL_DPT_HYBRID",
    "GEOFILL_MIDAS_SMALL",
    "GEOFILL_LAMA_MODEL",
):
    os.environ.pop(_var, None)

REPO = Path(__file__).resolve().parents[1]
PAIRS_DIR = REPO.parent / "shared" / "data" / "pairs"


@pytest.fixture(scope="session")
def pairs_dir() -> Path:
    if not PAIRS_DIR.is_dir():
        pytest.skip(f"real pairs not available ({PAIRS_DIR} missing)")
    return PAIRS_DIR
