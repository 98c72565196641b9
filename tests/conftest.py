"""Shared fixtures: real pairs from ../shared (skipped when absent); the ``needs`` marker, which
skips a test whose optional library is not installed and names the extra that installs it."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

from geofill.extras import EXTRAS, available

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
MULTIVIEW_DIR = REPO.parent / "shared" / "data" / "multiview"


@pytest.fixture(scope="session")
def pairs_dir() -> Path:
    if not PAIRS_DIR.is_dir():
        pytest.skip(f"real pairs not available ({PAIRS_DIR} missing)")
    return PAIRS_DIR


@pytest.fixture(scope="session")
def multiview_dir() -> Path:
    if not MULTIVIEW_DIR.is_dir():
        pytest.skip(f"real multi-reference sets not available ({MULTIVIEW_DIR} missing)")
    return MULTIVIEW_DIR


#: Libraries the tests use beside the package's extras (they build tiny ONNX graphs).
TEST_TOOLS = {"onnx": "dev"}


def missing_reason(module: str) -> str:
    """Why a test that needs ``module`` is skipped here: the extra that installs it."""
    extra = EXTRAS.get(module) or TEST_TOOLS[module]
    return f"{module} is not installed (the '{extra}' extra: pip install \"geofill[{extra}]\")"


def pytest_configure(config) -> None:
    config.addinivalue_line(
        "markers", "needs(*modules): skip unless every module can be imported; the reason names its extra"
    )


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures are set up (they may need the module too)
def pytest_runtest_setup(item) -> None:
    for mark in item.iter_markers("needs"):
        for module in mark.args:
            if not available(module):
                pytest.skip(missing_reason(module))
