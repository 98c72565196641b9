"""Several references in one fill, on ray-cast scenes whose references each see a different part
of the hole (exact geometry: :func:`geofill.synthetic.make_views`)."""

from __future__ import annotations

import numpy as np
import pytest

from geofill.composite.inpaint import inpaint_single
from geofill.composite.merge import merge_fill
from geofill.config import FillConfig
from geofill.evaluation.metrics import psnr
from geofill.pipeline import fill
from geofill.synthetic import blanked, make_views
from geofill.utils.resolution import config_px

# Focal from the default prior (the views' true focal): the test is about fusion, not focal.
CFG = FillConfig().updated({"intrinsics.estimate": "none"})


@pytest.fixture(scope="module")
def views():
    v = make_views(seed=0, width=320, height=240)
    hole = np.zeros((240, 320), bool)
    hole[60:180, :50] = True  # seen by reference 1 only (stepped and turned left)
    hole[60:180, 270:] = True  # seen by reference 2 only
    assert v.visible[0][60:180, :50].mean() > 0.95 and not v.visible[1][60:180, :50].any()
    assert v.visible[1][60:180, 270:].mean() > 0.95 and not v.visible[0][60:180, 270:].any()
    return v, hole


@pytest.fixture(scope="module")
def fills(views):
    v, hole = views
    return {
        "left": fill(blanked(v.target, hole), hole, [v.sources[0]], CFG),
        "right": fill(blanked(v.target, hole), hole, [v.sources[1]], CFG),
        "both": fill(blanked(v.target, hole), hole, v.sources, CFG),
    }


def test_each_part_of_the_hole_comes_from_the_reference_that_sees_it(views, fills):
    _, hole = views
    both = fills["both"]
    left, right = hole.copy(), hole.copy()
    left[:, 160:], right[:, :160] = False, False
    m = both.source_map
    assert np.mean(m[left & (m > 0)] == 1) > 0.99 and np.mean(m[right & (m > 0)] == 2) > 0.99
    # Together they supply what each supplies alone; alone, each paints more than half the hole.
    assert fills["left"].report.painted_fraction > 0.5 and fills["right"].report.painted_fraction > 0.5
    f = both.report.supplied_fraction
    assert f[0] == pytest.approx(fills["left"].report.supplied_fraction[0], abs=0.02)
    assert f[1] == pytest.approx(fills["right"].report.supplied_fraction[0], abs=0.02)
    assert both.report.painted_fraction < 0.2
    assert both.report.painted_fraction == pytest.approx(1 - f[0] - f[1])


def test_fused_fill_matches_the_ground_truth_where_a_reference_sees_it(views, fills):
    v, hole = views
    seen = hole & (v.visible[0] | v.visible[1])
    both = fills["both"]
    single_image = psnr(inpaint_single(v.target, hole, CFG.inpaint), v.target, seen)
    assert psnr(both.image, v.target, seen) > single_image + 3.0
    # Where a reference supplies the fused fill, it is as good as that reference's fill alone.
    for k, alone in ((1, fills["left"]), (2, fills["right"])):
        mine = (both.source_map == k) & (alone.source_map == 1)
        assert psnr(both.image, v.target, mine) > psnr(alone.image, v.target, mine) - 0.5
    assert np.array_equal(both.image[~hole], v.target[~hole])


def test_reference_order_does_not_change_the_fill(views, fills):
    v, hole = views
    swapped = fill(blanked(v.target, hole), hole, v.sources[::-1], CFG)
    assert np.array_equal(swapped.image, fills["both"].image)
    assert swapped.report.supplied_fraction == fills["both"].report.supplied_fraction[::-1]


def test_a_noise_image_among_the_references_is_dropped_with_its_reason(views, fills):
    v, hole = views
    noise = np.random.default_rng(0).integers(0, 256, v.target.shape, dtype=np.uint8)
    res = fill(blanked(v.target, hole), hole, [v.sources[0], noise, v.sources[1]], CFG)
    ref = res.report.references[1]
    # The matching ladder finds a few chance matches in noise; the pose stage turns them down.
    assert ref["status"] == "dropped" and ("match" in ref["reason"] or "pose" in ref["reason"])
    assert res.report.supplied_fraction[1] == 0.0 and "depth" not in ref
    assert any(f.startswith("reference 2:") for f in res.report.fallbacks)
    assert np.array_equal(res.image, fills["both"].image)


def test_one_reference_is_the_single_reference_fill(views, fills):
    """With one reference, fusion passes its refined render through unchanged: the fill is the
    feathered merge of that render with single-image inpainting, as before several references."""
    v, hole = views
    res = fills["left"]
    ref = res.references[0]
    assert res.fusion.method == "single reference"
    feather = config_px(CFG.refine.feather_px, hole.shape)
    from geofill.composite.inpaint import get_inpainter

    masked = v.target.copy()
    masked[hole] = 0
    expected = merge_fill(
        masked, hole, ref.refined.image, ref.refined.alpha, get_inpainter(CFG.inpaint), feather
    )
    assert np.array_equal(res.image, expected)
    assert np.array_equal(
        fill(blanked(v.target, hole), hole, v.sources[0], CFG).image, res.image
    )  # one image, not a list


def test_stop_after_a_stage_and_resume(views, fills):
    from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_reference

    v, hole = views
    ctx = prepare_fill(blanked(v.target, hole), hole, [v.sources[0]], CFG)
    ref = ReferenceArtifacts(1, v.sources[0])
    early = run_reference(ctx, ref, until="depth")
    assert early.depth is not None and early.geometry is None and early.render is None
    done = run_reference(ctx, early)
    assert done.usable and done.depth is early.depth  # resumed: the depth stage did not run again
    assert np.array_equal(done.refined.image, fills["left"].references[0].refined.image)
    with pytest.raises(ValueError, match="unknown stage"):
        run_reference(ctx, ref, until="nonsense")


def test_one_focal_from_all_references_of_one_camera():
    """Three references of one camera whose focal is 1.3x the default guess: the focal estimated
    from all pairs together is within 5 % of the truth and shared by every reference."""
    from geofill.camera import default_focal_px
    from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_reference, shared_focal

    f_true = 1.3 * default_focal_px(320, 240)
    motions = (("orbit", -0.8, None), ("orbit", 0.8, None), ("sideways", 0.5, 8.0))
    v = make_views(seed=1, width=320, height=240, motions=motions, focal_px=f_true)
    hole = np.zeros((240, 320), bool)
    hole[100:140, 140:180] = True
    # The shared focal stage itself (the joint registration would replace its focal).
    cfg = FillConfig().updated({"intrinsics.shared_camera": "yes", "registration.joint": "off"})
    ctx = prepare_fill(blanked(v.target, hole), hole, v.sources, cfg)
    refs = [run_reference(ctx, ReferenceArtifacts(i + 1, s), until="match") for i, s in enumerate(v.sources)]
    joint = shared_focal(refs, cfg)
    focals = {r.focal.K_target.fx for r in joint}
    assert len(focals) == 1 and all(r.focal.status == "estimated" for r in joint)
    assert focals.pop() == pytest.approx(f_true, rel=0.05)
    assert {r.focal.K_source.fx for r in joint} == {joint[0].focal.K_target.fx}
    # The fill runs the same shared estimate when the user says the camera is shared.
    res = fill(blanked(v.target, hole), hole, v.sources, cfg)
    assert "shared focal" in res.report.timings_s
    assert res.report.references[0]["focal"]["method"] == "shared"
