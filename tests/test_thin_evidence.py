"""Downstream of a weak match set: the joint optimisation keeps the initial geometry when the
matches come from an unverified ladder rung or too few of them land on the source depth, and the
fill's report lists it as a fallback; with enough evidence it runs as before."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from geofill.config import FillConfig
from geofill.optimize.stage import optimize_geometry
from geofill.pipeline import ReferenceArtifacts, fill, prepare_fill, run_reference
from geofill.synthetic import make_pair

CFG = FillConfig()


@pytest.fixture(scope="module")
def before_optimize():
    """A synthetic pair run up to the depth stage (the optimisation's inputs)."""
    p = make_pair(seed=0, width=320, height=240)
    ctx = prepare_fill(p.target, p.hole, [p.source], CFG)
    return run_reference(ctx, ReferenceArtifacts(1, p.source), until="depth")


def _optimize(a, matches=None, **cfg):
    return optimize_geometry(
        a.views, a.focal, a.pose, a.depth, matches or a.matches, replace(CFG.optimize, **cfg)
    )


def test_enough_evidence_optimises(before_optimize):
    a = before_optimize
    n_inliers = int(a.pose.inliers.sum())
    assert n_inliers >= 40 and a.matches.verified
    g = _optimize(a)
    assert not g.thin and g.optimization is not None and g.optimization.status == "accepted"


def test_unverified_rung_keeps_the_initial_geometry(before_optimize):
    a = before_optimize
    g = _optimize(a, replace(a.matches, rung="asift", verified=False))
    assert g.thin and g.optimization is None
    assert g.skipped == "matches from an unverified asift rung: too thin to optimise"
    np.testing.assert_array_equal(g.T, a.pose.T)
    np.testing.assert_array_equal(g.depth, a.depth.depth)
    assert g.K_target == a.focal.K_target


def test_too_few_matches_on_depth_keep_the_initial_geometry(before_optimize):
    a = before_optimize
    inl = a.pose.inliers
    z = a.depth.aligned.depth
    ys, xs = np.round(a.matches.pts_source[inl]).astype(int).T[::-1]
    on_depth = int(np.isfinite(z[ys, xs]).sum())  # nearest pixel: the count the stage gets up to edges
    assert on_depth >= 40
    kept = _optimize(a, min_features=10_000)
    assert kept.thin and kept.skipped.startswith("only ") and "optimize.min_features = 10000" in kept.skipped
    count = int(kept.skipped.split()[1])
    assert abs(count - on_depth) <= 2
    runs = _optimize(a, min_features=count)  # exactly enough
    assert not runs.thin and runs.optimization is not None
    assert _optimize(a, min_features=count + 1).thin


def test_the_fill_report_lists_the_kept_geometry():
    p = make_pair(seed=0, width=320, height=240)
    cfg = replace(CFG, optimize=replace(CFG.optimize, min_features=10_000))
    result = fill(p.target, p.hole, [p.source], cfg)
    assert result.report.status == "reference"
    assert any("initial geometry kept: only" in f for f in result.report.fallbacks), result.report.fallbacks
    assert result.report.references[0]["optimize"]["status"] == "skipped"
    assert np.array_equal(result.image[~p.hole], p.target[~p.hole])
