"""What a batch is made of: masks matched by stem, one mask for all, references per image, manifests
(good rows, bad rows reported with their line numbers), and references picked by measured overlap."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from geofill.batch import items_from_folders, read_manifest
from geofill.batch.references import pick_references
from geofill.config import FillConfig
from geofill.errors import InputError
from geofill.io import LoadedImage
from geofill.synthetic import make_pair


def _touch_images(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        assert cv2.imwrite(str(folder / name), np.zeros((8, 8, 3), np.uint8))


def test_masks_matched_by_stem(tmp_path):
    _touch_images(tmp_path / "img", ["a.png", "b.jpg", "c.png"])
    _touch_images(tmp_path / "masks", ["a.png", "b.png", "x.png"])
    _touch_images(tmp_path / "src" / "a", ["s1.jpg", "s0.png"])
    _touch_images(tmp_path / "src" / "b", ["s.png"])
    items = items_from_folders(tmp_path / "img", tmp_path / "masks", sources_per_image=tmp_path / "src")
    by = {i.name: i for i in items}
    assert list(by) == ["a", "b", "c"]
    assert by["a"].mask == str(tmp_path / "masks" / "a.png") and not by["a"].error
    assert by["b"].mask == str(tmp_path / "masks" / "b.png")  # b.jpg's mask is b.png
    assert by["a"].sources == (str(tmp_path / "src/a/s0.png"), str(tmp_path / "src/a/s1.jpg"))
    assert by["c"].error == f"{tmp_path / 'img/c.png'}: no mask with stem 'c' in {tmp_path / 'masks'}"
    # Each output keeps its target's format; --format names one for all.
    assert [i.output for i in items] == ["a.png", "b.jpg", "c.png"]
    png = items_from_folders(
        tmp_path / "img", tmp_path / "masks", sources_per_image=tmp_path / "src", output_format="png"
    )
    assert [i.output for i in png] == ["a.png", "b.png", "c.png"]
    jpeg = items_from_folders(
        tmp_path / "img", tmp_path / "masks", sources_per_image=tmp_path / "src", output_format="jpeg"
    )
    assert [i.output for i in jpeg] == ["a.jpg", "b.jpg", "c.jpg"]


def test_one_mask_for_all_and_sources_exclude_the_target(tmp_path):
    _touch_images(tmp_path / "shoot", ["a.png", "b.png", "c.png"])
    _touch_images(tmp_path, ["mask.png"])
    items = items_from_folders(
        tmp_path / "shoot", tmp_path / "mask.png", sources=tmp_path / "shoot", max_refs=2
    )
    assert all(i.mask == str(tmp_path / "mask.png") and not i.error for i in items)
    shoot = tmp_path / "shoot"
    assert items[1].candidates == (str(shoot / "a.png"), str(shoot / "c.png"))
    assert items[1].max_refs == 2 and items[1].sources == ()


def test_same_stem_twice_and_missing_folders(tmp_path):
    _touch_images(tmp_path / "img", ["a.png", "a.jpg"])
    _touch_images(tmp_path / "masks", ["a.png"])
    items = items_from_folders(tmp_path / "img", tmp_path / "masks", sources=tmp_path / "masks")
    assert [(i.output, i.error) for i in items] == [("a.jpg", ""), ("a.png", "")]  # formats kept apart
    items = items_from_folders(
        tmp_path / "img", tmp_path / "masks", sources=tmp_path / "masks", output_format="png"
    )
    assert not items[0].error
    assert (
        items[1].error
        == f"{tmp_path / 'img/a.png'}: output a.png is already written by {tmp_path / 'img/a.jpg'}"
    )
    with pytest.raises(InputError, match="not a folder"):
        items_from_folders(tmp_path / "nope", tmp_path / "masks", sources=tmp_path / "masks")
    with pytest.raises(InputError, match="exactly one of"):
        items_from_folders(tmp_path / "img", tmp_path / "masks")


CSV = """target,mask,sources,output,set
t1.png,m1.png,s1.png,,
t2.png,m2.png,s2a.png;s2b.png,second.jpg,optimize.enabled=false;working_max_side=640
t3.png,,s3.png,,
t4.png,m4.png,s4.png,,nosuch.key=1
t5.png,m5.png,s5.png,out/escape.png,
t6.png,m6.png,s6.png,,,extra
t7.png,m7.png,s7.png,t1.png,
"""


def test_manifest_csv_rows_and_line_numbers(tmp_path):
    path = tmp_path / "batch.csv"
    path.write_text(CSV)
    items = read_manifest(path, FillConfig())
    assert len(items) == 7
    good1, good2 = items[0], items[1]
    assert (good1.target, good1.mask, good1.sources, good1.output) == (
        str(tmp_path / "t1.png"),
        str(tmp_path / "m1.png"),
        (str(tmp_path / "s1.png"),),
        "t1.png",
    )
    assert good2.sources == (str(tmp_path / "s2a.png"), str(tmp_path / "s2b.png"))
    assert good2.output == "second.jpg" and good2.name == "second"
    assert dict(good2.overrides) == {"optimize.enabled": False, "working_max_side": 640}
    errors = {i.where: i.error for i in items if i.error}
    assert set(errors) == {f"{path}:{n}" for n in (4, 5, 6, 7, 8)}
    assert errors[f"{path}:4"] == f"{path}:4: 'mask' is missing or empty"
    assert errors[f"{path}:5"] == f"{path}:5: unknown config section 'nosuch' in 'nosuch.key'"
    assert "must be a file name" in errors[f"{path}:6"]
    assert errors[f"{path}:7"] == f"{path}:7: 6 cells for 5 columns"
    assert errors[f"{path}:8"] == f"{path}:8: output t1.png is already written by {path}:2"


def test_manifest_outputs_keep_the_targets_format_unless_named(tmp_path):
    path = tmp_path / "batch.csv"
    path.write_text(
        "target,mask,sources,output\nshot.JPG,m.png,s.jpg,\nscan.tiff,m.png,s.jpg,\n"
        "raw.heic,m.png,s.jpg,\nnamed.jpg,m.png,s.jpg,clean.png\n"
    )
    outputs = [i.output for i in read_manifest(path, FillConfig())]
    # HEIC is read, not written: PNG (lossless) stands in for it.
    assert outputs == ["shot.JPG", "scan.tiff", "raw.png", "clean.png"]
    outputs = [i.output for i in read_manifest(path, FillConfig(), output_format="webp")]
    assert outputs == ["shot.webp", "scan.webp", "raw.webp", "clean.png"]  # a named output wins


def test_manifest_jsonl_rows_and_line_numbers(tmp_path):
    path = tmp_path / "batch.jsonl"
    rows = [
        json.dumps({"target": "/abs/t.png", "mask": "m.png", "sources": "s.png"}),
        "",
        "{not json",
        json.dumps(
            {
                "target": "u.png",
                "mask": "m.png",
                "sources": ["a.png", "b.png"],
                "set": {"depth.backend": "sparse"},
            }
        ),
        json.dumps({"target": "v.png", "mask": "m.png", "sources": [], "colour": 1}),
        json.dumps({"target": "w.png", "mask": "m.png", "sources": []}),
        json.dumps(["a", "list"]),
    ]
    path.write_text("\n".join(rows) + "\n")
    items = read_manifest(path, FillConfig())
    assert [i.where for i in items] == [f"{path}:{n}" for n in (1, 3, 4, 5, 6, 7)]
    assert items[0].target == "/abs/t.png" and items[0].sources == (str(tmp_path / "s.png"),)
    assert items[2].overrides == {"depth.backend": "sparse"} and not items[2].error
    assert items[1].error.startswith(f"{path}:3: not valid JSON")
    assert items[3].error.startswith(f"{path}:5: unknown field(s) colour")
    assert items[4].error == f"{path}:6: 'sources' must name one or more reference images"
    assert items[5].error == f"{path}:7: expected a JSON object, got list"


def test_manifest_header_errors_stop_before_anything(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("target,mask,refs\nt.png,m.png,s.png\n")
    with pytest.raises(
        InputError, match=r"m.csv:1: header missing column\(s\) sources; unknown column\(s\) refs"
    ):
        read_manifest(path, FillConfig())
    with pytest.raises(InputError, match="manifest not found"):
        read_manifest(tmp_path / "none.csv", FillConfig())


def test_pick_references_by_overlap_around_the_hole():
    """On a rendered scene: two real views of it are picked best first, a noise image and a view of
    another scene are not, and --max-refs caps the count."""
    pair = make_pair(seed=3, width=320, height=240)
    near = make_pair(seed=3, width=320, height=240, baseline=0.25)  # same scene, closer viewpoint
    other_scene = make_pair(seed=11, width=320, height=240)
    noise = np.random.default_rng(0).integers(0, 256, pair.source.shape, dtype=np.uint8)
    candidates = [
        LoadedImage(noise, "noise.png"),
        LoadedImage(pair.source, "orbit.png"),
        LoadedImage(other_scene.source, "other_scene.png"),
        LoadedImage(near.source, "near.png"),
    ]
    cfg = FillConfig()
    picked, scores = pick_references(pair.target, pair.hole, candidates, cfg, max_refs=3)
    by = {s.path: s for s in scores}
    assert [s.path for s in scores] == ["noise.png", "orbit.png", "other_scene.png", "near.png"]
    assert by["noise.png"].matches_near_hole < cfg.geometry.min_inliers
    assert by["other_scene.png"].matches_near_hole < cfg.geometry.min_inliers
    assert {p.path for p in picked} == {"orbit.png", "near.png"}
    assert by["orbit.png"].matches_near_hole >= cfg.geometry.min_inliers
    assert by["near.png"].matches_near_hole >= cfg.geometry.min_inliers
    best = max(("orbit.png", "near.png"), key=lambda p: by[p].matches_near_hole)
    assert picked[0].path == best
    assert all(s.matches_near_hole <= s.matches_verified for s in scores)
    one, _ = pick_references(pair.target, pair.hole, candidates, cfg, max_refs=1)
    assert [p.path for p in one] == [best]


def test_reference_masks_beside_the_references(tmp_path):
    """``<stem>.mask.png`` beside a reference is its mask: never a reference, never a target; a mask
    with no reference of its stem fails its item (per-image folders) or the batch (--sources)."""
    _touch_images(tmp_path / "img", ["a.png", "b.png"])
    _touch_images(tmp_path / "masks", ["a.png", "b.png"])
    _touch_images(tmp_path / "src" / "a", ["s0.png", "s0.mask.png", "s1.jpg"])
    _touch_images(tmp_path / "src" / "b", ["s.png", "x.mask.png"])
    items = items_from_folders(tmp_path / "img", tmp_path / "masks", sources_per_image=tmp_path / "src")
    a, b = items
    src = tmp_path / "src"
    assert a.sources == (str(src / "a/s0.png"), str(src / "a/s1.jpg")) and not a.error
    assert a.reference_masks == {str(src / "a/s0.png"): str(src / "a/s0.mask.png")}
    assert b.error == (
        f"{tmp_path / 'img/b.png'}: {src / 'b/x.mask.png'}: reference mask without a reference: "
        "no image named x.* beside it"
    )

    # one folder for targets and references: b.mask.png masks b.png when b.png is a's reference
    shoot = tmp_path / "shoot"
    _touch_images(shoot, ["a.png", "b.png", "b.mask.png"])
    items = items_from_folders(shoot, tmp_path / "masks", sources=shoot, max_refs=2)
    assert [i.name for i in items] == ["a", "b"]
    assert items[0].candidates == (str(shoot / "b.png"),)
    assert items[0].reference_masks == {str(shoot / "b.png"): str(shoot / "b.mask.png")}
    assert items[1].candidates == (str(shoot / "a.png"),) and items[1].reference_masks == {}
    _touch_images(shoot, ["c.mask.png"])
    with pytest.raises(InputError, match=r"c\.mask\.png: reference mask without a reference"):
        items_from_folders(shoot, tmp_path / "masks", sources=shoot)


def test_manifest_source_masks_follow_the_sources(tmp_path):
    csv_path = tmp_path / "batch.csv"
    csv_path.write_text(
        "target,mask,sources,source_masks\n"
        "t1.png,m.png,s1.png;s2.png,k1.png;\n"
        "t2.png,m.png,s1.png;s2.png,;k2.png\n"
        "t3.png,m.png,s1.png;s2.png,k1.png\n"
        "t4.png,m.png,s1.png,k1.png;k2.png\n"
        "t5.png,m.png,s1.png,\n"
    )
    items = read_manifest(csv_path, FillConfig())
    s1, s2, k1, k2 = (str(tmp_path / n) for n in ("s1.png", "s2.png", "k1.png", "k2.png"))
    assert items[0].reference_masks == {s1: k1} and not items[0].error
    assert items[1].reference_masks == {s2: k2}
    assert items[2].reference_masks == {s1: k1}  # fewer masks than sources: the last ones have none
    assert items[3].error == (
        f"{csv_path}:5: 2 source masks for 1 sources (one per source, in their order; empty for none)"
    )
    assert items[4].reference_masks == {} and not items[4].error

    jsonl_path = tmp_path / "batch.jsonl"
    rows = [
        {
            "target": "t1.png",
            "mask": "m.png",
            "sources": ["s1.png", "s2.png"],
            "source_masks": [None, "k2.png"],
        },
        {"target": "t2.png", "mask": "m.png", "sources": "s1.png", "source_masks": "/abs/k.png"},
        {"target": "t3.png", "mask": "m.png", "sources": ["s1.png"], "source_masks": [3]},
    ]
    jsonl_path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    items = read_manifest(jsonl_path, FillConfig())
    assert items[0].reference_masks == {s2: k2}
    assert items[1].reference_masks == {s1: "/abs/k.png"}
    assert items[2].error == f"{jsonl_path}:3: 'source_masks' must list a mask file (or nothing) per source"


def test_masked_matches_do_not_count_when_picking_references():
    """A candidate whose view of the hole is masked scores no matches there and is not picked."""
    pair = make_pair(seed=3, width=320, height=240)
    near = make_pair(seed=3, width=320, height=240, baseline=0.25)
    candidates = [LoadedImage(pair.source, "orbit.png"), LoadedImage(near.source, "near.png")]
    everything = np.ones(pair.source.shape[:2], bool)
    cfg = FillConfig()
    picked, scores = pick_references(
        pair.target,
        pair.hole,
        candidates,
        cfg,
        max_refs=2,
        masks={"orbit.png": ("orbit.mask.png", everything)},
    )
    by = {s.path: s for s in scores}
    assert by["orbit.png"].matches_near_hole == 0 and by["orbit.png"].matches_verified > 0
    assert by["orbit.png"].to_dict()["mask"] == "orbit.mask.png" and "mask" not in by["near.png"].to_dict()
    assert [p.path for p in picked] == ["near.png"]
    left = np.zeros_like(everything)
    left[:, :160] = True
    _, half = pick_references(pair.target, pair.hole, candidates[:1], cfg, 1, {"orbit.png": ("m.png", left)})
    _, none = pick_references(pair.target, pair.hole, candidates[:1], cfg, 1)
    assert 0 < half[0].matches_near_hole < none[0].matches_near_hole
