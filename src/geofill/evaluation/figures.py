"""The evaluation's pictures: the hole-size sweep's plot and each pair's contact sheet (restoration
and removal protocols)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from .pairs import Pair
from .removal import RemovalCase
from .tables import EvalRow, fmt_number, mean_or_none, ok_values


def plot_sweep(
    path: Path, rows: Sequence[EvalRow], methods: Sequence[str], widths_720p: Sequence[float]
) -> None:
    """Mean whole-image and hole PSNR per method vs. stroke width, and (as in the paper's figure)
    each method's mean per-pair PSNR gain over the homography baseline when it was run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    reference = "homography" if "homography" in methods else None
    panels = [("psnr", "PSNR (dB), whole image"), ("psnr_hole", "PSNR (dB), hole only")]
    fig, axes = plt.subplots(1, len(panels) + (reference is not None), figsize=(5 * (len(panels) + 1), 4))
    widths = [float(w) for w in widths_720p]
    for ax, (metric, title) in zip(axes, panels, strict=False):
        for m in methods:
            means = [
                mean_or_none(
                    ok_values([r for r in rows if r.method == m and r.stroke_width_720p == w], metric)
                )
                for w in widths
            ]
            ax.plot(widths, [np.nan if v is None else v for v in means], marker="o", label=m)
        ax.set_title(title)
    if reference is not None:
        ax = axes[-1]
        for m in methods:
            if m == reference:
                continue
            gains = []
            for w in widths:
                at_w = [r for r in rows if r.stroke_width_720p == w]
                ref = {r.pair: r.psnr for r in at_w if r.method == reference and r.ok}
                diffs = [r.psnr - ref[r.pair] for r in at_w if r.method == m and r.ok and r.pair in ref]
                gains.append(np.mean(diffs) if diffs else np.nan)
            ax.plot(widths, gains, marker="o", label=m)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_title(f"PSNR gain over {reference} (dB)")
    for ax in axes:
        ax.set_xlabel("mean stroke width (px at 720p)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


#: Long side (px) of each tile of a contact sheet.
_TILE_LONG_SIDE = 400
_LABEL_H = 24
_SHEET_COLUMNS = 3
_HOLE_COLOUR = (255, 0, 255)


def _tile(image: np.ndarray, label: str, cell_hw: tuple[int, int]) -> np.ndarray:
    ch, cw = cell_hw
    h, w = image.shape[:2]
    s = min(ch / h, cw / w)
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    tile = np.full((ch + _LABEL_H, cw, 3), 255, np.uint8)
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
    y0, x0 = _LABEL_H + (ch - nh) // 2, (cw - nw) // 2
    tile[y0 : y0 + nh, x0 : x0 + nw] = resized
    cv2.putText(tile, label, (4, _LABEL_H - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return tile


def _cell_size(image: np.ndarray) -> tuple[int, int]:
    h, w = image.shape[:2]
    s = _TILE_LONG_SIDE / max(h, w)
    return max(1, round(h * s)), max(1, round(w * s))


def _output_tiles(
    results: Sequence[tuple[EvalRow, np.ndarray | None]], like: np.ndarray, cell: tuple[int, int]
) -> list[np.ndarray]:
    """One tile per method: its output labelled with its hole PSNR (and leak, when measured), or
    FAILED on grey."""
    tiles = []
    for row, image in results:
        if image is None:
            tiles.append(_tile(np.full_like(like, 128), f"{row.method}: FAILED", cell))
            continue
        label = f"{row.method}: hole PSNR {fmt_number(row.psnr_hole, 2)} dB"
        if row.distinguishable_px is not None:
            label = (
                f"{row.method}: {fmt_number(row.psnr_hole, 2)} dB, leak {fmt_number(row.leak, 2)}, "
                f"ghost {fmt_number(row.ghost, 2)}"
            )
        tiles.append(_tile(image, label, cell))
    return tiles


def _grid(tiles: list[np.ndarray]) -> np.ndarray:
    while len(tiles) % _SHEET_COLUMNS:
        tiles.append(np.full_like(tiles[0], 255))
    rows = [np.hstack(tiles[i : i + _SHEET_COLUMNS]) for i in range(0, len(tiles), _SHEET_COLUMNS)]
    return np.vstack(rows)


def contact_sheet(
    pair: Pair, hole: np.ndarray, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> np.ndarray:
    """RGB grid: ground truth, masked target (hole in magenta), source, then each method's output
    labelled with its hole PSNR (or FAILED)."""
    cell = _cell_size(pair.target)
    masked = pair.target.copy()
    masked[hole] = _HOLE_COLOUR
    tiles = [
        _tile(pair.target, f"{pair.id} (ground truth)", cell),
        _tile(masked, f"masked target, hole {hole.mean():.1%}", cell),
        _tile(pair.source, "source", cell),
    ]
    return _grid(tiles + _output_tiles(results, pair.target, cell))


def removal_contact_sheet(
    case: RemovalCase, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> np.ndarray:
    """RGB grid of a removal case: ground truth, the target as the methods get it (showing the
    object) with the hole's outline in magenta, every reference as the methods get it (with the
    object or strangers), then each method's output labelled with hole PSNR and leak."""
    pair = case.pair
    cell = _cell_size(pair.target)
    shown = pair.target.copy()
    outline = case.hole & ~cv2.erode(case.hole.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    shown[outline] = _HOLE_COLOUR
    what = "strangers" if case.protocol == "strangers" else "object"
    tiles = [
        _tile(case.truth, f"{pair.id} (ground truth)", cell),
        _tile(shown, f"target given, hole {case.hole.mean():.1%}", cell),
    ]
    tiles += [_tile(source, f"reference {k + 1} with {what}", cell) for k, source in enumerate(pair.sources)]
    return _grid(tiles + _output_tiles(results, case.truth, cell))


def write_contact_sheet(
    path: Path, pair: Pair, hole: np.ndarray, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> None:
    """:func:`contact_sheet` as a JPEG."""
    sheet = contact_sheet(pair, hole, results)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])


def write_removal_contact_sheet(
    path: Path, case: RemovalCase, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> None:
    """:func:`removal_contact_sheet` as a JPEG."""
    sheet = removal_contact_sheet(case, results)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
