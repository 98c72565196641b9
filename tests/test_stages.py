"""Every stage result owns its progress line (``summary()``) and its report.json section
(``report()``), and every progress line is a record of the ``geofill`` logger."""

from __future__ import annotations

import io
import json
import logging
import re

import numpy as np
import pytest

from geofill.config import FillConfig
from geofill.pipeline import REFERENCE_STAGES, fill
from geofill.progress import Progress
from geofill.synthetic import make_pair


@pytest.fixture(scope="module")
def filled():
    """One quiet fill of a synthetic pair, with every log record of the ``geofill`` logger."""
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append
    logger = logging.getLogger("geofill")
    old_level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        pair = make_pair(seed=0, width=320, height=240)
        result = fill(pair.target, pair.hole, [pair.source])
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old_level)
    return result, [r.getMessage() for r in records]


STAGES = [*(name for name, _ in REFERENCE_STAGES), "fuse"]


@pytest.mark.parametrize("stage", STAGES)
def test_stage_result_summary_and_report(filled, stage):
    result, messages = filled
    if stage == "fuse":
        artifact, section = result.fusion, result.report.fusion
    else:
        ref = result.references[0]
        artifact = getattr(ref, dict(REFERENCE_STAGES)[stage])
        section = result.report.references[0][stage]
    summary = artifact.summary()
    assert isinstance(summary, str) and summary and "\n" not in summary
    # The line the progress shows for the stage ends with the result's own summary.
    lines = [m for m in messages if re.match(rf"{stage} +\d+\.\d\d s  ", m)]
    assert len(lines) == 1 and lines[0].endswith(f"  {summary}"), lines
    # report() is the stage's section of report.json, and survives JSON as it is.
    report = artifact.report()
    assert isinstance(report, dict) and report
    assert json.loads(json.dumps(report)) == json.loads(json.dumps(section))


def test_quiet_progress_logs_without_printing(caplog):
    stream = io.StringIO()
    prog = Progress(quiet=True, stream=stream).child("ref 2")
    with caplog.at_level(logging.INFO, logger="geofill"), prog.stage("match") as notes:
        notes.append("12 matches")
    assert stream.getvalue() == ""
    [record] = caplog.records
    assert record.name == "geofill" and record.levelno == logging.INFO
    assert record.getMessage().startswith("ref 2: match") and record.getMessage().endswith("12 matches")


def test_loud_progress_prints_and_logs_the_same_line(caplog):
    stream = io.StringIO()
    with caplog.at_level(logging.INFO, logger="geofill"):
        Progress(quiet=False, stream=stream).say("depth backend: stereo")
    assert stream.getvalue() == "geofill: depth backend: stereo\n"
    assert [r.getMessage() for r in caplog.records] == ["depth backend: stereo"]


def test_an_embedder_filters_progress_with_logging(caplog):
    logger = logging.getLogger("geofill")

    def no_backend_lines(record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("depth backend")

    logger.addFilter(no_backend_lines)
    try:
        with caplog.at_level(logging.INFO, logger="geofill"):
            prog = Progress(quiet=True)
            prog.say("depth backend: stereo")
            prog.say("reference 2 cannot help: too few matches")
    finally:
        logger.removeFilter(no_backend_lines)
    assert [r.getMessage() for r in caplog.records] == ["reference 2 cannot help: too few matches"]


class _Fractions(Progress):
    """A quiet progress that keeps every done fraction it reports."""

    def __init__(self) -> None:
        super().__init__(quiet=True)
        self.seen: list[float] = []

    def on_fraction(self, before: float, now: float) -> None:
        self.seen.append(now)


def test_done_fraction_of_a_three_reference_fill_only_grows():
    """Three references, two run at a time in threads, one that cannot help (noise): the fraction
    the progress reports grows one stage at a time up to 1, never back."""
    pair = make_pair(seed=0, width=320, height=240)
    noise = np.random.default_rng(0).integers(0, 256, pair.source.shape, dtype=np.uint8)
    prog = _Fractions()
    cfg = FillConfig().updated({"fusion.parallel": 2})
    result = fill(pair.target, pair.hole, [pair.source, noise, pair.source], cfg, progress=prog)
    assert [r["status"] for r in result.report.references] == ["used", "dropped", "used"]
    assert prog.seen == sorted(prog.seen) and prog.seen[-1] == 1.0
    assert len(prog.seen) > 20  # 1 + 3 x 10 + 1 + 2 stages planned; the dropped one jumps ahead
    assert 0 < result.report.wall_s < sum(result.report.timings_s.values())
