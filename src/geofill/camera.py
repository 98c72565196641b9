"""Pinhole intrinsics and relative poses.

Conventions used across geofill:
- pixel coordinates: pixel (0, 0) has its centre at (0.0, 0.0); x right, y down (OpenCV);
- camera axes: x right, y down, z forward (OpenCV);
- a pose is a 4x4 float64 matrix mapping a 3D point from SOURCE camera coordinates to TARGET
  camera coordinates, ``X_t = R @ X_s + t``; the translation has the units of the depth it is
  used with (unit norm straight out of the essential matrix).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

#: The paper's fixed focal length (px) for its 1280x720 images.
PAPER_FOCAL_PX = 750.0
#: Long side (px) the paper's focal refers to; other sizes scale by their long side, so a portrait
#: image gets the same field of view along its long axis as a landscape one.
PAPER_LONG_SIDE_PX = 1280


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of one image, in pixels of that image.

    ``origin`` says where the focal length came from: ``default`` (paper's 750 px scaled by the
    long side), ``exif`` (35 mm-equivalent focal), ``flag`` (user override), ``estimated`` (from
    the pair) or ``refined`` (by the joint optimisation); ``rel_uncertainty`` is a 1-sigma relative
    error of the focal when known.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    origin: str = "default"
    rel_uncertainty: float | None = None

    @property
    def K(self) -> np.ndarray:
        """3x3 float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def K_inv(self) -> np.ndarray:
        """Inverse of :attr:`K`."""
        return np.linalg.inv(self.K)

    @classmethod
    def from_focal(
        cls, focal_px: float, width: int, height: int, origin: str = "default", rel_uncertainty=None
    ) -> Intrinsics:
        """Square pixels, principal point at the image centre."""
        return cls(
            float(focal_px),
            float(focal_px),
            (width - 1) / 2.0,
            (height - 1) / 2.0,
            int(width),
            int(height),
            origin,
            rel_uncertainty,
        )

    @classmethod
    def from_matrix(cls, K: np.ndarray, width: int, height: int, origin: str = "given") -> Intrinsics:
        K = np.asarray(K, dtype=np.float64)
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], int(width), int(height), origin)

    def resized(self, width: int, height: int) -> Intrinsics:
        """Intrinsics of the same camera after resizing the image to ``width`` x ``height``
        (pixel-centre convention: ``c' = s (c + 0.5) - 0.5``)."""
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=sx * (self.cx + 0.5) - 0.5,
            cy=sy * (self.cy + 0.5) - 0.5,
            width=int(width),
            height=int(height),
        )

    def with_focal(self, focal_px: float, origin: str, rel_uncertainty: float | None = None) -> Intrinsics:
        """Same principal point and size, new (square-pixel) focal length."""
        return replace(
            self, fx=float(focal_px), fy=float(focal_px), origin=origin, rel_uncertainty=rel_uncertainty
        )

    def to_json(self) -> dict:
        return {
            "fx_px": self.fx,
            "fy_px": self.fy,
            "cx_px": self.cx,
            "cy_px": self.cy,
            "width": self.width,
            "height": self.height,
            "origin": self.origin,
            "rel_uncertainty": self.rel_uncertainty,
        }


def default_focal_px(width: int, height: int) -> float:
    """The paper's 750 px at a 1280-px long side, scaled linearly with the long side."""
    return PAPER_FOCAL_PX * max(width, height) / PAPER_LONG_SIDE_PX


def focal_from_35mm(f35_mm: float, width: int, height: int) -> float:
    """Focal length in pixels from a 35 mm-equivalent focal length (EXIF FocalLengthIn35mmFilm).

    The equivalence is defined on the diagonal of the 36x24 mm frame (43.27 mm), which keeps it
    right for 4:3 and 16:9 sensors, unlike a width-based rule."""
    return float(f35_mm) * float(np.hypot(width, height)) / float(np.hypot(36.0, 24.0))


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 source->target pose from a rotation matrix and a translation vector."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of a rotation vector (axis times angle in radians): OpenCV's Rodrigues,
    instead of SciPy's ``Rotation``, which is not worth its import on the fill path
    (:mod:`geofill.utils.numerics`)."""
    return cv2.Rodrigues(np.asarray(rotvec, np.float64).reshape(3, 1))[0]


def quaternion_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix, with the sign SciPy's
    ``Rotation.from_matrix(R).as_quat()`` gives: built from the largest of the diagonal entries
    and the trace (Markley's method), which keeps it accurate near every angle."""
    R = np.asarray(R, np.float64)
    diag = np.array([R[0, 0], R[1, 1], R[2, 2], np.trace(R)])
    i = int(np.argmax(diag))
    q = np.empty(4)  # x, y, z, w
    if i == 3:
        q[:] = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], 1.0 + diag[3]
    else:
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1.0 - diag[3] + 2.0 * R[i, i]
        q[j] = R[j, i] + R[i, j]
        q[k] = R[k, i] + R[i, k]
        q[3] = R[k, j] - R[j, k]
    q /= np.linalg.norm(q)
    return np.array([q[3], q[0], q[1], q[2]])


def rotation_error_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle (degrees) between two rotation matrices."""
    cos = (np.trace(np.asarray(R_a).T @ np.asarray(R_b)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def translation_direction_error_deg(t_a: np.ndarray, t_b: np.ndarray) -> float:
    """Angle (degrees) between two translation directions; sign matters (no abs)."""
    a = np.asarray(t_a, dtype=np.float64).reshape(3)
    b = np.asarray(t_b, dtype=np.float64).reshape(3)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-12 or nb < 1e-12:
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(a @ b / (na * nb), -1.0, 1.0))))


def pose_errors_deg(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[float, float]:
    """(rotation error, translation-direction error) in degrees of an estimated pose vs. ground truth."""
    return (
        rotation_error_deg(T_est[:3, :3], T_gt[:3, :3]),
        translation_direction_error_deg(T_est[:3, 3], T_gt[:3, 3]),
    )
