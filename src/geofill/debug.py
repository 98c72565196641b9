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


#: Coverage colours: reference k uses PALETTE[(k - 1) % len]; single-image inpainting is red.
PALETTE = np.array(
    [(0, 200, 0), (0, 120, 255), (255, 200, 0), (200, 0, 255), (0, 220, 220), (255, 120, 0)], np.uint8
)
PAINTED = np.array((220, 0, 0), np.uint8)


def coverage_rgb(result: FillResult) -> np.ndarray:
    """HxWx3 uint8: the target dimmed outside the hole; inside, each reference's pixels in its
    :data:`PALETTE` colour and single-image inpainting in red."""
    m = result.source_map
    out = (result.image.astype(np.float32) * 0.35).astype(np.uint8)
    out[m == 0] = PAINTED
    for k in np.unique(m[m > 0]):
        out[m == k] = PALETTE[(int(k) - 1) % len(PALETTE)]
    return out


def _to_u8(image: np.ndarray) -> np.ndarray:
    return (np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8)


#: Widest tile of the overview, in tile heights: a 4000x64 photo scaled to the tiles' height would be
#: 18750 px wide, and a row of four past JPEG's 65500-px limit.
_TILE_MAX_ASPECT = 3


def _tile(image: np.ndarray, text: str, height: int, swatch: np.ndarray | None = None) -> np.ndarray:
    """``image`` scaled to ``height`` (or to ``_TILE_MAX_ASPECT`` heights wide, then below the
    label and padded to ``height`` with black) with ``text`` on a black label, underlined in
    ``swatch``."""
    h, w = image.shape[:2]
    f = min(height / h, _TILE_MAX_ASPECT * height / w)
    size = (max(round(w * f), 1), max(round(h * f), 1))
    out = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    top = min(28, height - out.shape[0])
    out = np.pad(out, ((top, height - out.shape[0] - top), (0, 0), (0, 0)))
    cv2.rectangle(out, (0, 0), (min(out.shape[1], 10 + 9 * len(text)), 22), (0, 0, 0), -1)
    if swatch is not None:
        out[22:28, : min(out.shape[1], 10 + 9 * len(text))] = swatch
    cv2.putText(out, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def overview_sheet(result: FillResult, target: np.ndarray, hole: np.ndarray, height: int = 300) -> np.ndarray:
    """One picture of the fill: target with the hole, each reference (with its share of the hole
    or why it was dropped), the fill and the coverage, on rows of at most four tiles."""
    marked = target.copy()
    marked[hole] = (marked[hole] * 0.4 + np.array([255, 0, 255]) * 0.6).astype(np.uint8)
    tiles = [_tile(marked, "target + hole", height)]
    for ref, frac in zip(result.references, result.report.supplied_fraction, strict=True):
        note = f"ref {ref.index}: dropped" if ref.dropped else f"ref {ref.index}: {100 * frac:.0f}% of hole"
        tiles.append(_tile(ref.source, note, height, PALETTE[(ref.index - 1) % len(PALETTE)]))
    tiles.append(_tile(result.image, "fill", height))
    painted = f"coverage ({100 * result.report.painted_fraction:.0f}% painted)"
    tiles.append(_tile(coverage_rgb(result), painted, height, PAINTED))
    rows, width = [], max(sum(t.shape[1] for t in tiles[i : i + 4]) for i in range(0, len(tiles), 4))
    for i in range(0, len(tiles), 4):
        row = np.concatenate(tiles[i : i + 4], axis=1)
        rows.append(np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0))))
    return np.concatenate(rows, axis=0)


def write_debug(out_dir: str | Path, result: FillResult, hole: np.ndarray, cfg: FillConfig) -> list[Path]:
    """Write the debug images and report.json into ``out_dir`` (created); returns the paths.
    Per reference ``i``: ``matches_<i>.jpg``, ``depth_<i>.png``/``.npy``, ``warped_<i>.png`` (the
    rendered source), ``refined_<i>.png``; for the fill: ``coverage.png`` (per-reference colours,
    red = single-image inpainting), ``overview.jpg`` and ``report.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def save(name: str, rgb: np.ndarray) -> None:
        write_image_atomic(out / name, rgb)
        written.append(out / name)

    for ref in result.references:
        i = ref.index
        if ref.views is not None and ref.matches is not None:
            v = ref.views
            target = _to_u8(v.target)
            target[v.hole] = (target[v.hole] * 0.4 + np.array([255, 0, 255]) * 0.6).astype(np.uint8)
            m = ref.matches
            save(f"matches_{i}.jpg", draw_matches(target, _to_u8(v.source), m.pts_target, m.pts_source))
        if ref.depth is not None:
            save(f"depth_{i}.png", colourise(1.0 / ref.depth.depth))
            np.save(out / f"depth_{i}.npy", ref.depth.depth)
            written.append(out / f"depth_{i}.npy")
        if ref.render is not None:
            save(f"warped_{i}.png", ref.render.warped)
        if ref.refined is not None:
            save(f"refined_{i}.png", ref.refined.image)  # after residual flow and colour correction
    save("coverage.png", coverage_rgb(result))
    save("overview.jpg", overview_sheet(result, result.image, hole))
    report = result.report.to_dict() | {"config": cfg.to_dict()}
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    written.append(out / "report.json")
    return written
