"""The real removal panel's brush and proxies (benchmarks/quality/real_panel.py) on known pixels."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: benchmarks
from benchmarks.quality import real_panel


def _disc(shape: tuple[int, int], centre: tuple[int, int], radius: int) -> np.ndarray:
    mask = np.zeros(shape, np.uint8)
    cv2.circle(mask, centre, radius, 1, -1)
    return mask.astype(bool)


def test_wobbly_brush_keeps_its_margin_range_around_the_object() -> None:
    obj = _disc((640, 1280), (640, 320), 60)
    brush = real_panel.wobbly_brush(obj, (15, 45), seed=3)
    distance = cv2.distanceTransform((~obj).astype(np.uint8), cv2.DIST_L2, 5)
    assert brush[obj].all()
    assert distance[brush].max() <= 45.5  # nothing beyond the widest margin
    assert distance[~brush].min() >= 14.5  # nothing closer than the narrowest is left out
    # It wobbles: along the outline the margin spans most of its range.
    edge = cv2.morphologyEx(brush.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)).astype(
        bool
    )
    margins = distance[edge & brush]
    assert margins.max() - margins.min() > 15


def test_echo_finds_the_object_moved_and_not_in_a_plain_fill() -> None:
    rng = np.random.default_rng(0)
    target = np.full((200, 300, 3), 120, np.uint8)
    obj = _disc((200, 300), (150, 100), 20)
    target[obj] = rng.integers(0, 255, (int(obj.sum()), 3))
    hole = _disc((200, 300), (150, 100), 50)
    case = real_panel.Case("t", "", target, [], obj, hole, "")
    background = np.full_like(target, 120)
    moved = np.roll(target, 9, axis=1)  # the object copied back 9 px to the right
    moved[~hole] = target[~hole]
    assert real_panel.echo(moved, case, background) > 0.99
    assert real_panel.echo(background, case, background) < 1e-3


def test_a_case_without_its_data_is_skipped(tmp_path, capsys) -> None:
    case = {
        "name": "nowhere",
        "what": "",
        "data": {"shared": "pairs/no_such_pair", "repo": "a/b", "commit": "0" * 40, "licence": "x"},
        "margin_px": [15, 45],
        "object": [[[0, 0], [10, 0], [10, 10]]],
    }
    manifest = tmp_path / "cases.json"
    manifest.write_text(json.dumps({"cases": [case]}))
    assert real_panel.main(["--manifest", str(manifest), "--out", str(tmp_path / "out")]) == 0
    assert capsys.readouterr().out.startswith("nowhere: skipped, ")
    assert not list((tmp_path / "out").iterdir())


def test_tint_counts_the_objects_colours_at_another_size() -> None:
    target = np.full((200, 300, 3), (120, 120, 120), np.uint8)
    obj = np.zeros((200, 300), bool)
    obj[70:130, 120:180] = True  # a red square, 3600 px
    target[obj] = (200, 30, 30)
    hole = np.zeros((200, 300), bool)
    hole[50:150, 100:200] = True
    case = real_panel.Case("t", "", target, [], obj, hole, "")
    smaller = np.where(hole[..., None], np.uint8(120), target)
    smaller[85:115, 135:165] = (200, 30, 30)  # the square back at half its side: a quarter of it
    assert real_panel.tint(smaller, case) == 0.25
    assert real_panel.tint(np.where(hole[..., None], np.uint8(120), target), case) == 0.0
    grey = np.where(obj[..., None], np.uint8(125), target)  # an object coloured like its ground
    assert real_panel.tint(grey, real_panel.Case("t", "", grey, [], obj, hole, "")) is None


def test_score_table_sums_each_methods_scores(tmp_path) -> None:
    proxies = {"back": 0.5, "echo": 0.25, "tint": None}
    record = {
        "revision": "abc1234",
        "cases": {
            n: {
                "references": 1,
                "geofill_where": "painted 100%",
                "methods": dict.fromkeys(real_panel.METHODS, proxies),
            }
            for n in ("a", "b")
        },
    }
    (tmp_path / "run.json").write_text(json.dumps(record))
    scored = {"a": {"geofill": [3, "clean"], "telea": [1, "smear"], "homography": [0, "back"]}}
    scored["b"] = {"geofill": [0, "back"], "telea": [1, "smear"], "homography": [0, "back"]}
    runs = {"runs": [{"name": "x", "record": str(tmp_path / "run.json"), "sheets": "s/", "cases": scored}]}
    (tmp_path / "scores.json").write_text(json.dumps(runs))
    table = real_panel.score_table(tmp_path / "scores.json")
    assert "| a | 1 | **3** clean (back 0.50, echo 0.25, tint n/a) |" in table
    assert "- geofill: mean 1.50 over 2 cases, 1 score >= 2 (50 %), 1 score 0" in table
    assert "- homography: mean 0.00 over 2 cases, 0 score >= 2 (0 %), 2 score 0" in table


def test_a_fill_that_raises_is_that_cases_result(tmp_path, monkeypatch) -> None:
    def crash(*args, **kwargs):
        raise ValueError("cannot convert float NaN to integer")

    monkeypatch.setattr(real_panel, "fill", crash)
    target = np.full((120, 160, 3), 120, np.uint8)
    obj = _disc((120, 160), (80, 60), 15)
    target[obj] = (200, 30, 30)
    case = real_panel.Case("crash", "", target, [target.copy()], obj, _disc((120, 160), (80, 60), 30), "")
    record = real_panel.run_case(case, tmp_path)
    assert record["methods"]["geofill"] == {"failed": "ValueError: cannot convert float NaN to integer"}
    assert record["geofill_where"] == "ValueError: cannot convert float NaN to integer"
    assert record["methods"]["telea"]["tint"] == 0.0  # the other methods still ran
    assert (tmp_path / "crash.jpg").is_file()
