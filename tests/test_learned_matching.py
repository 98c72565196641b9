"""The learned matching rung with matcher graphs built here (no weights can be had offline): a
graph that returns the exact correspondences of a rendered wide pair is climbed to, verified and
mapped back to the images' pixels; an unresolved matcher is skipped with its reason under
``auto`` and is a one-line error under ``on``; ``geofill models`` lists it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from geofill.config import MatchingConfig
from geofill.errors import MatcherModelError
from geofill.match import match_pair
from geofill.models import registry
from geofill.synthetic import SyntheticPair, make_pair

onnx = pytest.importorskip("onnx", reason="onnx is not installed (the 'dev' extra)")
pytest.importorskip("onnxruntime", reason="onnxruntime is not installed (the 'onnx' extra)")
from onnx import TensorProto, helper  # noqa: E402

SCALE = 320 / 1280


@pytest.fixture(scope="module")
def wide() -> SyntheticPair:
    p = make_pair(0, baseline=4.0)
    p.target[p.hole] = 0
    return p


def _correspondences(p: SyntheticPair, step: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Target pixels on a grid outside the hole and their exact positions in the source."""
    h, w = p.hole.shape
    ys, xs = np.mgrid[step // 2 : h : step, step // 2 : w : step]
    pts_t = np.c_[xs.ravel(), ys.ravel()].astype(np.float64)
    pts_t = pts_t[~p.hole[pts_t[:, 1].astype(int), pts_t[:, 0].astype(int)]]
    z = p.scene.depth_at(p.K_target, p.target_to_world, pts_t)
    X_t = np.c_[pts_t, np.ones(len(pts_t))] @ np.linalg.inv(p.K_target).T * z[:, None]
    T_inv = np.linalg.inv(p.T_source_to_target)
    proj = (X_t @ T_inv[:3, :3].T + T_inv[:3, 3]) @ p.K_source.T
    pts_s = proj[:, :2] / proj[:, 2:]
    ok = (
        np.isfinite(z) & (pts_s[:, 0] > 0) & (pts_s[:, 0] < w - 1) & (pts_s[:, 1] > 0) & (pts_s[:, 1] < h - 1)
    )
    return pts_t[ok], pts_s[ok]


def _matcher_graph(path, pts_t: np.ndarray, pts_s: np.ndarray, f: float) -> str:
    """A pipeline-shaped graph: ``images`` (2, 1, H, W) -> the given keypoints (at the scale ``f``
    the matcher runs at), matches pairing them one to one, scores. The image enters the keypoints
    through a zero-weighted sum, so the graph really consumes its input."""
    n = len(pts_t)
    kps = np.stack([(pts_t + 0.5) * f - 0.5, (pts_s + 0.5) * f - 0.5]).astype(np.float32)
    matches = np.c_[np.zeros(n), np.arange(n), np.arange(n)].astype(np.int64)
    const = [
        helper.make_tensor("kp_const", TensorProto.FLOAT, kps.shape, kps.ravel()),
        helper.make_tensor("matches_const", TensorProto.INT64, matches.shape, matches.ravel()),
        helper.make_tensor("scores_const", TensorProto.FLOAT, (n,), np.ones(n, np.float32)),
        helper.make_tensor("zero", TensorProto.FLOAT, (), [0.0]),
    ]
    nodes = [
        helper.make_node("ReduceSum", ["images"], ["total"], keepdims=0),
        helper.make_node("Mul", ["total", "zero"], ["nothing"]),
        helper.make_node("Add", ["kp_const", "nothing"], ["keypoints"]),
        helper.make_node("Identity", ["matches_const"], ["matches"]),
        helper.make_node("Identity", ["scores_const"], ["mscores"]),
    ]
    graph = helper.make_graph(
        nodes,
        "tiny_matcher",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [2, 1, "H", "W"])],
        [
            helper.make_tensor_value_info("keypoints", TensorProto.FLOAT, [2, n, 2]),
            helper.make_tensor_value_info("matches", TensorProto.INT64, [n, 3]),
            helper.make_tensor_value_info("mscores", TensorProto.FLOAT, [n]),
        ],
        initializer=const,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


#: Plain SIFT and the loose rung starved of keypoints, so that the ladder climbs to the learned rung.
STARVED = MatchingConfig(max_features=40, loose_max_features=40, max_rung="loose", learned="off")


def test_ladder_climbs_to_the_learned_rung_and_maps_matches_back(wide, tmp_path):
    pts_t, pts_s = _correspondences(wide)
    assert len(pts_t) > 200
    # The matcher runs at a long side of 160 px: half the 320-px images.
    path = _matcher_graph(tmp_path / "m.onnx", pts_t, pts_s, f=0.5)
    cfg = replace(STARVED, learned="auto", learned_model=path, learned_max_side=160, unrelated_max_verified=0)
    m = match_pair(wide.target, wide.source, wide.hole, cfg, SCALE)
    assert [r.rung for r in m.rungs] == ["sift", "learned"]
    assert m.rung == "learned" and m.verified
    assert m.rungs[0].n_verified < 40 <= m.rungs[1].n_verified
    assert len(m) >= 0.95 * len(pts_t)
    # Every verified match is one of the given correspondences, back in full-size pixels (float32
    # keypoints: to 1e-3 px).
    given, got = np.c_[pts_t, pts_s], np.c_[m.pts_target, m.pts_source]
    nearest = np.abs(got[:, None, :] - given[None]).max(axis=2).min(axis=1)
    assert nearest.max() < 1e-3


def test_auto_without_a_model_skips_the_rung_and_says_why(wide, tmp_path, monkeypatch):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.delenv("GEOFILL_MATCHER_MODEL", raising=False)
    onnx_auto = replace(STARVED, learned="auto", learned_matcher="onnx", unrelated_max_verified=0)
    m = match_pair(wide.target, wide.source, wide.hole, onnx_auto, SCALE)
    assert [r.rung for r in m.rungs] == ["sift", "loose"]
    (note,) = [n for n in m.notes if n.startswith("rung learned skipped")]
    assert "SuperPoint+LightGlue (ONNX) weights not available" in note
    off = match_pair(wide.target, wide.source, wide.hole, STARVED, SCALE)
    assert not any("learned" in n for n in off.notes)  # off: not a rung the user asked for


def test_required_matcher_that_cannot_be_used_is_one_line(wide, tmp_path, monkeypatch):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.delenv("GEOFILL_MATCHER_MODEL", raising=False)
    with pytest.raises(MatcherModelError, match="weights not available") as exc:
        match_pair(
            wide.target, wide.source, wide.hole, replace(STARVED, learned="on", learned_matcher="onnx"), SCALE
        )
    assert "\n" not in str(exc.value)
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(MatcherModelError, match="could not be loaded") as exc:
        match_pair(wide.target, wide.source, wide.hole, replace(STARVED, learned_model=str(bad)), SCALE)
    assert "\n" not in str(exc.value)


def test_models_registry_lists_the_matcher():
    (entry,) = [e for e in registry() if e.name == "superpoint-lightglue"]
    assert entry.spec.env_var == "GEOFILL_MATCHER_MODEL" and entry.spec.sha256 is None
    assert entry.path_key == "matching.learned_model"
