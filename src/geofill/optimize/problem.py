"""The problem data of one pair: target texture pyramids (alpha-premultiplied RGB, alpha, the
importance map W), the source pixels and keypoints as points, the bilinear sampler both solvers use,
and what a solver reports per pyramid level."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from ..camera import Intrinsics
from ..config import OptimizeConfig
from ..depth.align import sample_at
from .importance import importance_map
from .params import Points


def sample_target(texture: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples (C, N) of ``texture`` (1, C, H, W) at pixel positions (x, y); zero outside."""
    h, w = texture.shape[-2:]
    grid = torch.stack([x * (2.0 / (w - 1)) - 1.0, y * (2.0 / (h - 1)) - 1.0], dim=-1)
    out = F.grid_sample(
        texture, grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="zeros", align_corners=True
    )
    return out[0, :, 0]


@dataclass
class PhotoLevel:
    """One pyramid level: the target texture and the source pixels that are reprojected into it."""

    texture: torch.Tensor  # (1, 5, H, W): alpha-premultiplied target RGB, alpha, W
    gradients: torch.Tensor  # (1, 8, H, W): d/dx of channels 0-3, then d/dy (central differences)
    support: torch.Tensor  # (1, 1, H, W): W max-filtered by the fast solver's margin
    known_area: float  # |M|: sum of alpha at this level
    K_t: Intrinsics
    points: Points  # the photometric points: source pixels with a depth
    colour: torch.Tensor  # (N, 3) their RGB in [0, 1]
    all_values: torch.Tensor  # depth values of every source pixel of the level (L_negD)
    value_range: tuple[float, float]  # their min and max

    def subset(self, keep: torch.Tensor) -> PhotoLevel:
        """The same level with only the photometric points ``keep`` (L_negD still sees all pixels)."""
        return replace(self, points=self.points.take(keep), colour=self.colour[keep])


@dataclass
class FeatureSet:
    """Matched keypoints at the finest level: source points, target pixels, W at the target pixels."""

    points: Points
    q_t: torch.Tensor  # (M, 2)
    weight: torch.Tensor  # (M,)


@dataclass
class Problem:
    """Everything the objective needs; ``levels[0]`` is the finest."""

    levels: list[PhotoLevel]
    features: FeatureSet
    space: str
    cfg: OptimizeConfig
    barron_c: float  # px at the finest level
    prior_ref: float = 0.0  # l0 of the focal prior (set from the initial objective)


def _pyr_down(image: np.ndarray) -> np.ndarray:
    """``cv2.pyrDown`` of an (H, W, C) float32 image, C taken in groups OpenCV accepts."""
    parts = [cv2.pyrDown(np.ascontiguousarray(image[..., i : i + 4])) for i in range(0, image.shape[2], 4)]
    return np.concatenate([p.reshape(*p.shape[:2], -1) for p in parts], axis=2)


def _level_intrinsics(K: Intrinsics, level: int, width: int, height: int) -> Intrinsics:
    """Intrinsics after ``level`` pyrDown steps (pixel x of the coarser level = pixel 2x)."""
    s = 0.5**level
    return replace(K, fx=K.fx * s, fy=K.fy * s, cx=K.cx * s, cy=K.cy * s, width=width, height=height)


def _central_gradients(texture: torch.Tensor) -> torch.Tensor:
    """Central differences in x and y of (1, C, H, W), zero outside the image (as the sampler)."""
    p = F.pad(texture, (1, 1, 1, 1))
    gx = 0.5 * (p[..., 1:-1, 2:] - p[..., 1:-1, :-2])
    gy = 0.5 * (p[..., 2:, 1:-1] - p[..., :-2, 1:-1])
    return torch.cat([gx, gy], dim=1).contiguous()


def _resize_views(target, hole, source, values, K_t, K_s, pts_t, pts_s, max_side):
    """Everything downsized so that the longer of the two images has ``max_side`` px (no upsizing)."""
    s = min(1.0, max_side / max(*target.shape[:2], *source.shape[:2]))
    if s >= 1.0:
        return target, hole, source, values, K_t, K_s, pts_t, pts_s

    def size(img):
        return max(round(img.shape[1] * s), 8), max(round(img.shape[0] * s), 8)

    wt, ws = size(target), size(source)
    ok = np.isfinite(values)
    num = cv2.resize(np.where(ok, values, 0).astype(np.float32), ws, interpolation=cv2.INTER_AREA)
    den = cv2.resize(ok.astype(np.float32), ws, interpolation=cv2.INTER_AREA)
    with np.errstate(invalid="ignore", divide="ignore"):
        values_r = np.where(den > 0.5, num / den, np.nan).astype(np.float32)
    K_t2, K_s2 = K_t.resized(*wt), K_s.resized(*ws)

    def scale_pts(p, K_old, K_new):
        return (p + 0.5) * [K_new.width / K_old.width, K_new.height / K_old.height] - 0.5

    return (
        cv2.resize(target, wt, interpolation=cv2.INTER_AREA),
        cv2.resize(hole.astype(np.float32), wt, interpolation=cv2.INTER_AREA) > 0,
        cv2.resize(source, ws, interpolation=cv2.INTER_AREA),
        values_r,
        K_t2,
        K_s2,
        scale_pts(pts_t, K_t, K_t2),
        scale_pts(pts_s, K_s, K_s2),
    )


def build_problem(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    values: np.ndarray,
    space: str,
    K_t: Intrinsics,
    K_s: Intrinsics,
    pts_t: np.ndarray,
    pts_s: np.ndarray,
    cfg: OptimizeConfig,
) -> Problem:
    """Pyramids, weight map and point sets of one pair.

    ``target``/``source``: float32 RGB in [0, 1]; ``hole``: bool (target); ``values``: the source's
    depth (``space == "depth"``) or inverse depth (``"inverse"``) in pose units, NaN where unknown;
    ``pts_t``/``pts_s``: matched pixels (N, 2). All at the resolution of ``K_t``/``K_s``."""
    target, hole, source, values, K_t, K_s, pts_t, pts_s = _resize_views(
        target, hole, source, values, K_t, K_s, pts_t, pts_s, cfg.max_side
    )
    px_scale = max(*target.shape[:2], *source.shape[:2]) / 1280.0
    weight = importance_map(target, hole, cfg, px_scale)
    alpha = (~hole).astype(np.float32)
    tex = np.concatenate([target * alpha[..., None], alpha[..., None], weight[..., None]], axis=2)
    ok = np.isfinite(values)
    src = np.concatenate([source, np.where(ok, values, 0)[..., None], ok[..., None]], axis=2).astype(
        np.float32
    )
    margin = 2 * cfg.fast_margin_px + 1
    levels = []
    for k in range(cfg.pyramid_levels):
        if k:
            tex, src = _pyr_down(tex), _pyr_down(src)
        ht, wt = tex.shape[:2]
        hs, ws = src.shape[:2]
        den = src[..., 4]
        ok_k = den > 0.5
        val = np.where(ok_k, src[..., 3] / np.maximum(den, 1e-6), np.nan)
        ii, jj = np.nonzero(ok_k)
        K_sk = _level_intrinsics(K_s, k, ws, hs)
        texture = torch.from_numpy(np.ascontiguousarray(tex.transpose(2, 0, 1)))[None]
        support = cv2.dilate(np.ascontiguousarray(tex[..., 4]), np.ones((margin, margin), np.uint8))
        points = Points.from_pixels(np.stack([jj, ii], axis=1).astype(np.float64), K_sk, val[ii, jj])
        levels.append(
            PhotoLevel(
                texture=texture,
                gradients=_central_gradients(texture[:, :4]),
                support=torch.from_numpy(support)[None, None],
                known_area=float(tex[..., 3].sum()),
                K_t=_level_intrinsics(K_t, k, wt, ht),
                points=points,
                colour=torch.from_numpy(src[ii, jj, :3].copy()),
                all_values=points.value,
                value_range=(float(np.nanmin(val)), float(np.nanmax(val))) if ii.size else (1.0, 1.0),
            )
        )
    fv = sample_at(values, pts_s)
    fw = sample_at(weight, pts_t)
    keep = np.isfinite(fv) & np.isfinite(fw)
    features = FeatureSet(
        Points.from_pixels(pts_s[keep], K_s, fv[keep]),
        torch.from_numpy(pts_t[keep].astype(np.float32)),
        torch.from_numpy(fw[keep].astype(np.float32)),
    )
    return Problem(levels, features, space, cfg, cfg.barron_c_px * px_scale)


@dataclass
class LevelLog:
    """What one pyramid level did (level 0 = finest)."""

    level: int
    iterations: int
    objective: float  # best objective of this level (its own L_photo level)
    n_photo_points: int
    converged: bool

    def to_json(self) -> dict[str, Any]:
        return asdict(self)
