"""The fuse stage's bookkeeping: a single reference passes through untouched, and the labels,
source map and supplied fractions are computed on the renders' window only."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from geofill.camera import Intrinsics
from geofill.config import FillConfig
from geofill.fuse import Fusion, fuse_references, gaussian_blur
from geofill.render import RenderResult
from geofill.utils.distance import known_ring
from geofill.utils.windows import mask_window


def _single_reference(index: int = 2):
    h, w = 90, 120
    hole = np.zeros((h, w), bool)
    hole[20:60, 30:80] = True
    hole[85:, :5] = True  # a piece of the hole no render reaches
    roi = (20, 10, 95, 70)
    alpha = np.zeros((h, w), bool)
    alpha[12:68, 22:93] = True
    alpha[40:50, 50:60] = False
    image = np.zeros((h, w, 3), np.uint8)
    image[alpha] = 123
    empty = np.full((h, w), -1.0, np.float32)
    render = RenderResult(empty, empty, np.full((h, w), np.inf, np.float32), alpha, roi)
    refined = SimpleNamespace(image=image, alpha=alpha, render=render)
    return hole, SimpleNamespace(index=index, refined=refined, screened=refined)


def test_single_reference_passes_its_render_through():
    hole, ref = _single_reference()
    target = np.full((*hole.shape, 3), 50, np.uint8)
    fusion = fuse_references(target, hole, [ref], FillConfig())
    assert fusion.image is ref.refined.image and fusion.alpha is ref.refined.alpha
    np.testing.assert_array_equal(fusion.labels, np.where(ref.refined.alpha & hole, 2, 0))
    assert fusion.labels.dtype == np.int16
    expected_map = np.where(hole, np.where(ref.refined.alpha & hole, 2, 0), -1)
    np.testing.assert_array_equal(fusion.source_map(hole), expected_map)
    supplied = (ref.refined.alpha & hole).sum() / hole.sum()
    np.testing.assert_allclose(fusion.supplied_fractions(hole, 3), [0.0, supplied, 0.0])
    assert (
        fusion.summary() == f"single reference: 1 reference(s) supply {(ref.refined.alpha & hole).sum()} px"
    )


def test_no_reference():
    hole, _ = _single_reference()
    fusion = fuse_references(np.zeros((*hole.shape, 3), np.uint8), hole, [], FillConfig())
    assert fusion.image is None and not fusion.labels.any()
    np.testing.assert_array_equal(fusion.source_map(hole), np.where(hole, 0, -1))
    assert fusion.supplied_fractions(hole, 1) == [0.0]


def test_window_defaults_to_the_whole_image():
    labels = np.zeros((4, 5), np.int16)
    labels[3, 4] = 1
    fusion = Fusion(np.zeros((4, 5, 3), np.uint8), labels > 0, labels, "test")
    hole = np.ones((4, 5), bool)
    assert fusion.supplied_fractions(hole, 1) == [1 / 20]


def test_known_ring_of_a_window_holding_the_hole_equals_the_whole_image():
    hole = np.zeros((200, 300), bool)
    hole[50:120, 80:200] = True
    hole[130:135, 60:70] = True
    whole = known_ring(hole, 16.0)
    assert whole.sum() > 0 and not (whole & hole).any()
    for margin in (0, 24):  # the bare bounding box, and one the whole ring fits in
        rows, cols = mask_window(hole, margin)
        np.testing.assert_array_equal(known_ring(hole[rows, cols], 16.0), whole[rows, cols])


@pytest.mark.parametrize("sigma", [3.0, 48.0])  # the direct filter, and the Fourier-domain one
def test_gaussian_blur_equals_opencvs_to_float_rounding(sigma):
    rng = np.random.default_rng(1)
    image = np.zeros((300, 260), np.float32)
    image[100:140, 20:200] = rng.random((40, 180))  # a ring-like band near one border
    ref = cv2.GaussianBlur(image, (0, 0), sigma)
    out = gaussian_blur(image, sigma)
    assert out.dtype == np.float32 and out.shape == image.shape
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5 * ref.max())


# Renders with known pixels and depths: a 120 x 160 target whose hole is a 60 x 80 box, every
# reference covering the whole window (hole and known ring) with the target's background (grey 100)
# unless told otherwise.
_H, _W = 120, 160
_HOLE = np.zeros((_H, _W), bool)
_HOLE[30:90, 40:120] = True
_DISC = np.zeros((_H, _W), bool)
cv2.circle(_DISC.view(np.uint8), (80, 60), 22, 1, -1)


def _reference(index: int, image: np.ndarray, depth: np.ndarray, refused_stranger=None, alpha=None):
    """A usable reference whose refined and screened render are ``image`` (HxWx3 uint8, any size)
    where ``alpha`` (all of it when None) at target-camera ``depth`` (its pair's own scale)."""
    h, w = image.shape[:2]
    alpha = np.ones((h, w), bool) if alpha is None else alpha
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    render = RenderResult(xs, ys, depth.astype(np.float32), alpha, None)
    refined = SimpleNamespace(image=image, alpha=alpha, render=render)
    screened = SimpleNamespace(image=image, alpha=alpha, refused_stranger=refused_stranger)
    K = Intrinsics(1.25 * w, 1.25 * w, w / 2, h / 2, w, h)
    T = np.eye(4)
    T[0, 3] = 0.1 * index  # the source camera beside the target's
    geometry = SimpleNamespace(K_target=K, T=T)
    source = np.full((h, w, 3), index, np.uint8)  # distinct content: the fuse stage sorts by it
    return SimpleNamespace(index=index, source=source, refined=refined, screened=screened, geometry=geometry)


def _grey(level: int) -> np.ndarray:
    return np.full((_H, _W, 3), level, np.uint8)


def _target() -> np.ndarray:
    target = _grey(100)
    target[_HOLE] = 0
    return target


def _hole_error(fusion) -> float:
    """Largest difference (grey levels) between the fused hole and the background (100)."""
    assert fusion.alpha[_HOLE].all()
    return float(np.abs(fusion.image[_HOLE].astype(int) - 100).max())


def test_a_stranger_outvoted_by_two_agreeing_references_is_refused():
    # The third reference shows a stranger (a red disc) wholly inside the hole; it also matches the
    # ring best (the others are 1 level off), so without the test it would be pasted.
    stranger = _grey(100)
    stranger[_DISC] = (200, 30, 30)
    refs = [
        _reference(1, _grey(101), np.full((_H, _W), 10.0)),
        _reference(2, _grey(101), np.full((_H, _W), 20.0)),
    ]
    refs.append(_reference(3, stranger, np.full((_H, _W), 30.0)))
    cfg = FillConfig().updated({"fusion.consensus_scale": 255.0})
    off = fuse_references(_target(), _HOLE, refs, cfg.updated({"fusion.cross_strangers": "off"}))
    assert (off.image[_DISC] == (200, 30, 30)).all() and off.refused_stranger is None
    fusion = fuse_references(_target(), _HOLE, refs, cfg)
    assert _hole_error(fusion) <= 4
    refused = fusion.refused_stranger
    assert refused[_DISC].mean() > 0.97  # the disc, and no more than a few pixels around it
    assert refused.sum() < 1.15 * _DISC.sum()
    assert fusion.report()["refused_stranger_px"] == int(refused.sum())


def test_of_two_disagreeing_references_the_one_continuing_a_refused_stranger_is_refused():
    # Two references; the first shows a stranger inside the hole that its own stranger test found
    # reaching out of the hole just beside it (refused there: ``refused_stranger``).
    stranger = _grey(100)
    stranger[_DISC] = (30, 30, 200)
    evidence = np.zeros((_H, _W), bool)
    evidence[30:40, 70:90] = True  # the disc's top, by the hole's top edge
    first = _reference(1, stranger, np.full((_H, _W), 10.0), refused_stranger=evidence & _HOLE)
    second = _reference(2, _grey(101), np.full((_H, _W), 20.0))
    fusion = fuse_references(_target(), _HOLE, [first, second], FillConfig())
    assert _hole_error(fusion) <= 4
    assert fusion.refused_stranger[_DISC].mean() > 0.97
    # Without that evidence nothing says which one is the stranger: the scores choose (the first).
    plain = _reference(1, stranger, np.full((_H, _W), 10.0))
    chosen = fuse_references(_target(), _HOLE, [plain, second], FillConfig())
    assert chosen.refused_stranger is None and (chosen.image[_DISC] == (30, 30, 200)).all()


def test_agreeing_references_are_averaged():
    rng = np.random.default_rng(3)
    noise = [np.clip(100 + rng.normal(0, 6, (_H, _W, 3)), 0, 255).astype(np.uint8) for _ in range(3)]
    refs = [_reference(k + 1, n, np.full((_H, _W), 10.0 * (k + 1))) for k, n in enumerate(noise)]
    single = fuse_references(_target(), _HOLE, refs, FillConfig())
    averaged = fuse_references(
        _target(), _HOLE, refs, FillConfig().updated({"fusion.average_agreement": 20.0})
    )
    err = lambda f: float(np.abs(f.image[_HOLE].astype(float) - 100).mean())  # noqa: E731
    assert err(averaged) < 0.8 * err(single)  # three independent errors (1/sqrt(3) before rounding)


def test_the_fuse_stages_refusals_are_reported_as_strangers():
    from geofill.pipeline import FillReport, _refused_fractions

    beside = np.zeros((_H, _W), bool)
    beside[30:40, 40:60] = True  # what the screen stage refused in one reference
    screened = SimpleNamespace(refused_object=None, refused_masked=None, refused_stranger=beside)
    fusion = Fusion(None, None, np.zeros((_H, _W), np.int16), "test", refused_stranger=_DISC)
    fractions = _refused_fractions(_HOLE, [SimpleNamespace(screened=screened)], fusion)
    stranger = (_DISC.sum() + beside.sum()) / _HOLE.sum()  # 0.36
    # No reference supplies anything here (labels 0): the rest of the hole no reference sees.
    assert fractions == {"stranger": pytest.approx(stranger), "unseen": pytest.approx(1 - stranger)}
    words = FillReport(refused_fraction=fractions, painted_fraction=1.0).refused_words()
    assert words.startswith("36% of the hole was not copied because the references showed something there")
    assert words.endswith(", 64% no reference sees")


def _covering(index: int, image: np.ndarray, alpha: np.ndarray | None = None):
    """:func:`_reference` at one depth."""
    return _reference(index, image, np.full(image.shape[:2], 10.0), alpha=alpha)


def test_a_render_that_does_not_line_up_with_the_ring_is_painted_over():
    # Reference 1 is 40 levels off the target on the ring (a wrong colour or a misplaced surface);
    # reference 2 matches but covers only the hole's left half.
    left = np.zeros((_H, _W), bool)
    left[:, :80] = True
    refs = [_covering(1, _grey(140)), _covering(2, _grey(100), left)]
    cfg = FillConfig().updated({"fusion.cross_strangers": "off", "fusion.feather_px": 0.0})
    fusion = fuse_references(_target(), _HOLE, refs, cfg)
    right = _HOLE & ~left
    assert not fusion.alpha[right].any()  # left to the painter
    assert (fusion.image[_HOLE & left] == 100).all()
    np.testing.assert_array_equal(fusion.refused_mismatch, right)
    assert fusion.report()["refused_mismatch_px"] == int(right.sum())
    # Off: every covered pixel is copied, the misfit too.
    off = fuse_references(_target(), _HOLE, refs, cfg.updated({"fusion.max_ring_error": 0.0}))
    assert off.refused_mismatch is None and (off.image[right] == 140).all()


def test_a_textured_ring_tolerates_more_difference_than_a_flat_one():
    # At 640 px the texture is measured against a 1-px blur. Stripes of 60 and 140 differ from it by
    # 37-39 levels; a render 25 levels brighter than the target is kept beside them (limit 15 + 37)
    # and refused beside a flat ring (limit 15 + 0).
    h, w = 480, 640
    hole = np.zeros((h, w), bool)
    hole[120:360, 160:480] = True
    stripes = np.full((h, w, 3), 60, np.uint8)
    stripes[:, ::2] = 140
    flat = np.full((h, w, 3), 100, np.uint8)
    cfg = FillConfig().updated({"fusion.cross_strangers": "off"})
    for target, kept in ((stripes, True), (flat, False)):
        brighter = (target.astype(int) + 25).astype(np.uint8)
        refs = [_covering(1, brighter), _covering(2, brighter)]
        shown = target.copy()
        shown[hole] = 0
        fusion = fuse_references(shown, hole, refs, cfg)
        assert fusion.alpha[hole].all() == kept
        assert (fusion.refused_mismatch is None) == kept
        no_texture = fuse_references(shown, hole, refs, cfg.updated({"fusion.ring_texture_factor": 0.0}))
        assert not no_texture.alpha[hole].any()


def test_the_fuse_stages_mismatch_refusals_are_reported_in_words():
    from geofill.pipeline import FillReport, _refused_fractions

    screened = SimpleNamespace(refused_object=None, refused_masked=None, refused_stranger=None)
    fusion = Fusion(None, None, np.zeros((_H, _W), np.int16), "test", refused_mismatch=_DISC)
    fractions = _refused_fractions(_HOLE, [SimpleNamespace(screened=screened)], fusion)
    share = _DISC.sum() / _HOLE.sum()  # 0.32
    assert fractions == {"mismatch": pytest.approx(share), "unseen": pytest.approx(1 - share)}
    words = FillReport(refused_fraction=fractions, painted_fraction=1.0).refused_words()
    assert words == (
        "32% of the hole was not copied because the references did not line up with your photo "
        "around it there, 68% no reference sees"
    )


def test_a_copy_that_disagrees_with_the_other_reference_is_named_in_the_last_line():
    # Two references cover the hole; the first shows a disc the second does not, and nothing decides
    # which is right (two cannot outvote each other): the disc is copied (it fits the ring best) and
    # the last line says that this much of the hole, from that reference, disagrees.
    from geofill.pipeline import FillReport

    with_disc = _grey(100)
    with_disc[_DISC] = (200, 30, 30)
    refs = [_covering(1, with_disc), _covering(2, _grey(104))]
    fusion = fuse_references(_target(), _HOLE, refs, FillConfig().updated({"fusion.feather_px": 0.0}))
    assert (fusion.image[_DISC] == (200, 30, 30)).all()
    disputed = fusion.disputed_fractions(_HOLE, 2)
    # The disc (0.32 of the hole) but its rim, where a box straddles it or a shift explains it.
    assert disputed[1] == 0.0 and 0.6 * _DISC.sum() / _HOLE.sum() < disputed[0] <= _DISC.sum() / _HOLE.sum()
    supplied = fusion.supplied_fractions(_HOLE, 2)
    report = FillReport(
        supplied_fraction=supplied, painted_fraction=1 - sum(supplied), disputed_fraction=disputed
    )
    assert report.refused_words(["left.jpg", "right.jpg"]) == (
        f"{100 * disputed[0]:.0f}% of the hole copied from left.jpg disagrees with the other references: "
        "check it"
    )
    # Agreeing references: nothing to check.
    same = fuse_references(
        _target(), _HOLE, [_covering(1, _grey(101)), _covering(2, _grey(104))], FillConfig()
    )
    assert same.disputed is None
