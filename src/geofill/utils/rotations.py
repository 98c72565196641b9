"""SO(3) and S² helpers for the solvers' analytic Jacobians (neither OpenCV nor SciPy exposes them).

>>> import numpy as np
>>> v, u = np.array([1.0, 2.0, 3.0]), np.array([4.0, 5.0, 6.0])
>>> bool(np.allclose(skew(v) @ u, np.cross(v, u)))
True
>>> B = tangent_basis(np.array([0.0, 0.0, 2.0]))
>>> bool(np.allclose(B.T @ B, np.eye(2))), bool(np.allclose(B.T @ [0, 0, 1], 0))
(True, True)
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """The 3x3 matrix [v]x with [v]x u = v x u."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


#: [v]x = sum_k v_k SKEW_GENERATORS[k]: the skew matrices of many vectors in one tensor product.
SKEW_GENERATORS = np.array([skew(e) for e in np.eye(3)])


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) at rotation vector ``w`` (radians)."""
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * W
    return np.eye(3) + (1.0 - np.cos(theta)) / theta**2 * W + (theta - np.sin(theta)) / theta**3 * W @ W


def tangent_basis(t: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane orthogonal to ``t`` (the tangent plane of S² at t/|t|)."""
    n = t / np.linalg.norm(t)
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    b1 = np.cross(n, a)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(n, b1)], axis=1)
