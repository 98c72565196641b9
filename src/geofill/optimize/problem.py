"""The problem data of one pair: target texture pyramids (alpha-premultiplied RGB, alpha, the
importance map W), the source pixels and keypoints as points, the bilinear sampler both solvers use,
and what a solver reports per pyramid level."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import cv2
import numpy as np
from array_api_compat import is_torch_array

from ..camera import Intrinsics
from ..config import OptimizeConfig
from ..depth.align import sample_at
from ..utils.jit import njit_cached
from .importance import importance_map
from .params import Points


def sample_target(texture: Any, x: Any, y: Any) -> Any:
    """Bilinear samples (C, N) of ``texture`` (H, W, C) at pixel positions (x, y); a tap outside the
    image counts as zero. NumPy arrays go through a compiled loop, torch tensors through
    ``grid_sample`` (differentiable, for the ``paper`` solver); both give the same values.

    >>> tex = np.arange(4, dtype=np.float32).reshape(2, 2, 1)
    >>> sample_target(tex, np.array([0.5, 1.5], np.float32), np.array([0.5, 0.0], np.float32)).tolist()
    [[1.5, 0.5]]
    """
    if is_torch_array(texture):
        import torch
        import torch.nn.functional as F

        h, w = texture.shape[:2]
        grid = torch.stack([x * (2.0 / (w - 1)) - 1.0, y * (2.0 / (h - 1)) - 1.0], dim=-1)
        out = F.grid_sample(
            texture.permute(2, 0, 1)[None],
            grid.view(1, 1, -1, 2),
            mode="bilinear",
            padding_mode="zeros",
            align_corners=True,
        )
        return out[0, :, 0]
    return _bilinear(texture, x, y, False)[0]


def sample_target_with_gradient(texture: np.ndarray, x: np.ndarray, y: np.ndarray):
    """:func:`sample_target` (C, N) with its derivatives in x and in y, each (C, N): the derivative of
    the bilinear interpolant itself (what autograd through ``grid_sample`` gives), in one pass."""
    return _bilinear(texture, x, y, True)


# Written by hand: OpenCV's remap has no derivative and scipy's map_coordinates neither (and both
# return one channel per call); one loop gives every channel and both derivatives per tap, and the
# channels-last layout makes a tap one cache line.
@njit_cached(nogil=True)
def _bilinear(texture, x, y, with_gradient):  # pragma: no cover - compiled
    h, w, c = texture.shape
    n = x.shape[0]
    out = np.zeros((c, n), np.float32)
    m = n if with_gradient else 0
    gx = np.zeros((c, m), np.float32)
    gy = np.zeros((c, m), np.float32)
    for i in range(n):
        xi, yi = np.float64(x[i]), np.float64(y[i])
        if not (xi > -1.0 and yi > -1.0 and xi < w and yi < h):
            continue
        x0, y0 = math.floor(xi), math.floor(yi)
        fx, fy = xi - x0, yi - y0
        for dy in range(2):
            yy = y0 + dy
            if yy < 0 or yy >= h:
                continue
            wy = fy if dy else 1.0 - fy
            sy = 1.0 if dy else -1.0
            for dx in range(2):
                xx = x0 + dx
                if xx < 0 or xx >= w:
                    continue
                wx = fx if dx else 1.0 - fx
                sx = 1.0 if dx else -1.0
                for k in range(c):
                    v = texture[yy, xx, k]
                    out[k, i] += wx * wy * v
                    if with_gradient:
                        gx[k, i] += sx * wy * v
                        gy[k, i] += wx * sy * v
    return out, gx, gy


@dataclass
class PhotoLevel:
    """One pyramid level: the target texture and the source pixels that are reprojected into it."""

    texture: Any  # (H, W, 5) float32: alpha-premultiplied target RGB, alpha, W
    gradients: Any  # (H, W, 8): d/dx of channels 0-3, then d/dy (central differences)
    support: Any  # (H, W, 1): W max-filtered by the fast solver's margin
    known_area: float  # |M|: sum of alpha at this level
    K_t: Intrinsics
    points: Points  # the photometric points: source pixels with a depth
    colour: Any  # (N, 3) their RGB in [0, 1]
    all_values: Any  # depth values of every source pixel of the level (L_negD)
    value_range: tuple[float, float]  # their min and max

    def subset(self, keep: Any) -> PhotoLevel:
        """The same level with only the photometric points ``keep`` (L_negD still sees all pixels)."""
        return replace(self, points=self.points.take(keep), colour=self.colour[keep])


@dataclass
class FeatureSet:
    """Matched keypoints at the finest level: source points, target pixels, W at the target pixels."""

    points: Points
    q_t: Any  # (M, 2)
    weight: Any  # (M,)


@dataclass
class Problem:
    """Everything the objective needs; ``levels[0]`` is the finest."""

    levels: list[PhotoLevel]
    features: FeatureSet
    space: str
    cfg: OptimizeConfig
    barron_c: float  # px at the finest level
    prior_ref: float = 0.0  # l0 of the focal prior (set from the initial objective)

    def as_torch(self) -> Problem:
        """The same problem with torch tensors sharing the NumPy arrays' memory (the ``paper``
        solver differentiates the objective with autograd)."""
        import torch

        def convert(obj: Any) -> Any:
            if isinstance(obj, np.ndarray):
                return torch.from_numpy(obj)
            if isinstance(obj, (PhotoLevel, FeatureSet, Points)):
                return replace(obj, **{f.name: convert(getattr(obj, f.name)) for f in fields(obj)})
            return obj

        return replace(self, levels=[convert(lv) for lv in self.levels], features=convert(self.features))


def _pyr_down(image: np.ndarray) -> np.ndarray:
    """``cv2.pyrDown`` of an (H, W, C) float32 image, C taken in groups OpenCV accepts."""
    parts = [cv2.pyrDown(np.ascontiguousarray(image[..., i : i + 4])) for i in range(0, image.shape[2], 4)]
    return np.concatenate([p.reshape(*p.shape[:2], -1) for p in parts], axis=2)


def _level_intrinsics(K: Intrinsics, level: int, width: int, height: int) -> Intrinsics:
    """Intrinsics after ``level`` pyrDown steps (pixel x of the coarser level = pixel 2x)."""
    s = 0.5**level
    return replace(K, fx=K.fx * s, fy=K.fy * s, cx=K.cx * s, cy=K.cy * s, width=width, height=height)


def _central_gradients(texture: np.ndarray) -> np.ndarray:
    """Central differences in x and y of (H, W, C), zero outside the image (as the sampler)."""
    p = np.pad(texture, ((1, 1), (1, 1), (0, 0)))
    gx = 0.5 * (p[1:-1, 2:] - p[1:-1, :-2])
    gy = 0.5 * (p[2:, 1:-1] - p[:-2, 1:-1])
    return np.ascontiguousarray(np.concatenate([gx, gy], axis=2))


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
        texture = np.ascontiguousarray(tex)
        support = cv2.dilate(np.ascontiguousarray(tex[..., 4]), np.ones((margin, margin), np.uint8))
        points = Points.from_pixels(np.stack([jj, ii], axis=1).astype(np.float64), K_sk, val[ii, jj])
        levels.append(
            PhotoLevel(
                texture=texture,
                gradients=_central_gradients(texture[..., :4]),
                support=support[..., None],
                known_area=float(tex[..., 3].sum()),
                K_t=_level_intrinsics(K_t, k, wt, ht),
                points=points,
                colour=src[ii, jj, :3].copy(),
                all_values=points.value,
                value_range=(float(np.nanmin(val)), float(np.nanmax(val))) if ii.size else (1.0, 1.0),
            )
        )
    fv = sample_at(values, pts_s)
    fw = sample_at(weight, pts_t)
    keep = np.isfinite(fv) & np.isfinite(fw)
    features = FeatureSet(
        Points.from_pixels(pts_s[keep], K_s, fv[keep]),
        pts_t[keep].astype(np.float32),
        fw[keep].astype(np.float32),
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
