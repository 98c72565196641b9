"""Shared fixtures: real pairs from ../shared (skipped when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAIRS_DIR = REPO.parent / "shared" / "data" / "pairs"


@pytest.fixture(scope="session")
def pairs_dir() -> Path:
    if not PAIRS_DIR.is_dir():
        pytest.skip(f"real pairs not available ({PAIRS_DIR} missing)")
    return PAIRS_DIR
