"""Sparse depth with duplicated points (SIFT puts several keypoints on one spot): the interpolation
must be the same as without the duplicates, and the same on every run."""

from __future__ import annotations

import numpy as np

from geofill.camera import Intrinsics
from geofill.config import DepthConfig
from geofill.depth import DepthContext
from geofill.depth.sparse import SparseDepth
from geofill.triangulate import TriangulatedPoints, project


def _context(points: TriangulatedPoints) -> DepthContext:
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 1.0, (120, 160, 3)).astype(np.float32)
    K = Intrinsics.from_focal(150.0, 160, 120)
    hole = np.zeros((120, 160), bool)
    return DepthContext(image, image, hole, K, K, None, points, (160, 120), DepthConfig())


def test_duplicated_points_interpolate_like_unique_ones():
    rng = np.random.default_rng(1)
    K = Intrinsics.from_focal(150.0, 160, 120)
    uv = rng.uniform([5, 5], [155, 115], (30, 2))
    xyz = np.column_stack([(uv - [K.cx, K.cy]) / K.fx, np.ones(30)]) * (4.0 + uv[:, :1] / 40.0)
    assert np.allclose(project(xyz, K), uv)

    def points(idx):
        n = len(idx)
        return TriangulatedPoints(xyz[idx], uv[idx], uv[idx], np.zeros(n), np.ones(n))

    unique = SparseDepth().predict(_context(points(np.arange(30)))).values
    dup = np.r_[np.arange(30), [3, 7, 7, 20]]  # 34 points, 30 distinct: K would exceed the sites
    runs = [SparseDepth().predict(_context(points(dup))).values for _ in range(3)]
    for values in runs:
        assert np.all(np.isfinite(values))
        np.testing.assert_array_equal(values, unique)
