"""``--debug-dir`` output: matches, depth, warped and refined source, coverage and the JSON report."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from .config import FillConfig
from .io import write_image_atomic
from .pipeline import FillResult


def colourise(values: np.ndarray) -> np.ndarray:
    """Map a float image to RGB uint8 (turbo colour map, 2-98 percentile range; NaN -> black)."""
    finite = np.isfinite(values)
    out = np.zeros((*values.shape, 3), np.uint8)
    if not finite.any():
        return out
    lo, hi = np.percentile(values[finite], [2, 98])
    norm = np.clip((values - lo) / max(hi - lo, 1e-12), 0, 1)
    rgb = cv2.applyColorMap((np.nan_to_num(norm) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1]
    out[finite] = rgb[finite]
    return out


def draw_matches(target: np.ndarray, source: np.ndarray, pts_t: np.ndarray, pts_s: np.ndarray) -> np.ndarray:
    """Target and source side by side (same height) with a line per match."""
    h = max(target.shape[0], source.shape[0])
    canvas = np.zeros((h, target.shape[1] + source.shape[1], 3), np.uint8)
    canvas[: target.shape[0], : target.shape[1]] = target
    canvas[: source.shape[0], target.shape[1] :] = source
    rng = np.random.default_rng(0)
    for a, b in zip(pts_t, pts_s, strict=True):
        colour = tuple(int(c) for c in rng.integers(64, 256, 3))
        pa = (round(a[0]), round(a[1]))
        pb = (round(b[0]) + target.shape[1], round(b[1]))
        cv2.line(canvas, pa, pb, colour, 1, cv2.LINE_AA)
        cv2.circle(canvas, pa, 2, colour, -1)
        cv2.circle(canvas, pb, 2, colour, -1)
    return canvas


def write_debug(out_dir: str | Path, result: FillResult, hole: np.ndarray, cfg: FillConfig) -> list[Path]:
    """Write the debug images and report.json into ``out_dir`` (created); returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    art, written = result.artifacts, []

    def save(name: str, rgb: np.ndarray) -> None:
        write_image_atomic(out / name, rgb)
        written.append(out / name)

    if art.views is not None and art.matches is not None:
        v = art.views
        to_u8 = lambda im: (np.clip(im, 0, 1) * 255 + 0.5).astype(np.uint8)  # noqa: E731
        target = to_u8(v.target)
        target[v.hole] = (target[v.hole] * 0.4 + np.array([255, 0, 255]) * 0.6).astype(np.uint8)
        save(
            "matches.jpg",
            draw_matches(target, to_u8(v.source), art.matches.pts_target, art.matches.pts_source),
        )
    if art.depth is not None:
        save("depth.png", colourise(1.0 / art.depth.depth))
        np.save(out / "depth.npy", art.depth.depth)
        written.append(out / "depth.npy")
    if art.warped is not None and art.render is not None:
        save("warped.png", art.warped)
        cov = np.zeros((*hole.shape, 3), np.uint8)
        cov[art.render.alpha] = (90, 90, 90)
        cov[hole & art.render.alpha] = (0, 200, 0)
        cov[hole & ~art.render.alpha] = (220, 0, 0)
        save("coverage.png", cov)  # green: hole filled from source; red: single-image inpainting
    if art.refined is not None:
        save("refined.png", art.refined.image)  # after residual flow and colour correction
    report = result.report.to_dict() | {"config": cfg.to_dict()}
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    written.append(out / "report.json")
    return written
