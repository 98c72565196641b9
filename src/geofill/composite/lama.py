"""LaMa (Suvorov et al., WACV 2022) single-image inpainting through ONNX Runtime.

Public LaMa ONNX exports differ in their I/O, so the session's declared inputs decide: either two
inputs, an image (1, 3, H, W) RGB in [0, 1] and a mask (1, 1, H, W) with 1 = hole (e.g.
Carve/LaMa-ONNX, fixed 512 x 512), or one (1, 4, H, W) input holding both. The output is
(1, 3, H, W) RGB, in [0, 1] or [0, 255] depending on the export (told apart by its range). A
fixed-size model gets a window around the hole resized to its size; a dynamic one gets the window
at a long side of at most :data:`DYNAMIC_MAX_SIDE`, padded to a multiple of 32. The result is
resized back and pasted only inside the hole.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from ..extras import require

#: Context around the hole's bounding box, as a fraction of its longer side (LaMa sees the hole's
#: surroundings; more context costs resolution inside a fixed-size model).
CONTEXT_FRACTION = 0.5
#: Minimum context (px of the input image) on each side of the hole's bounding box.
MIN_CONTEXT_PX = 32
#: Long side a dynamic-size model is run at (at most).
DYNAMIC_MAX_SIDE = 1024
#: Outputs whose maximum exceeds this are taken to be in [0, 255].
_RANGE_255_THRESHOLD = 2.0


class LamaOnnx:
    """A LaMa ONNX model; call it with (image HxWx3 uint8, region HxW bool) -> inpainted image."""

    def __init__(self, path: str | Path):
        ort = require("onnxruntime", "LaMa inpainting (inpaint.method lama)")
        self.path = Path(path)
        self.session = ort.InferenceSession(str(self.path), providers=["CPUExecutionProvider"])
        inputs = self.session.get_inputs()
        channels = [i.shape[1] if len(i.shape) == 4 else None for i in inputs]
        if len(inputs) == 2 and sorted(c for c in channels if isinstance(c, int)) == [1, 3]:
            self.image_name = inputs[channels.index(3)].name
            self.mask_name = inputs[channels.index(1)].name
        elif len(inputs) == 1 and channels[0] == 4:
            self.image_name, self.mask_name = inputs[0].name, None
        else:
            desc = ", ".join(f"{i.name}{list(i.shape)}" for i in inputs)
            raise ValueError(f"{self.path}: not a LaMa-style model (inputs {desc})")
        h, w = inputs[0].shape[2:]
        self.fixed_size = (w, h) if isinstance(h, int) and isinstance(w, int) else None

    def __call__(self, image: np.ndarray, region: np.ndarray) -> np.ndarray:
        """Inpaint ``region`` of ``image``; pixels outside it are returned unchanged."""
        out = image.copy()
        if not region.any():
            return out
        x0, y0, x1, y1 = crop_window(region, self.fixed_size)
        crop, mask = image[y0:y1, x0:x1], region[y0:y1, x0:x1]
        size = self.fixed_size or _dynamic_size(crop.shape[1], crop.shape[0])
        img = cv2.resize(crop, size, interpolation=_interp(crop.shape[1], size[0])).astype(np.float32) / 255.0
        # Any hole pixel under a model pixel makes it a hole: nothing of the hole's content leaks in.
        m = cv2.resize(mask.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0
        m = m.astype(np.float32)[None, None]
        img = np.transpose(img, (2, 0, 1))[None] * (1.0 - m)
        if self.mask_name is None:
            feeds = {self.image_name: np.concatenate([img, m], axis=1).astype(np.float32)}
        else:
            feeds = {self.image_name: img.astype(np.float32), self.mask_name: m}
        pred = np.asarray(self.session.run(None, feeds)[0], np.float32)[0].transpose(1, 2, 0)
        if float(pred.max()) > _RANGE_255_THRESHOLD:
            pred = pred / 255.0
        pred = np.clip(pred, 0.0, 1.0)
        ch, cw = crop.shape[:2]
        back = cv2.resize(pred, (cw, ch), interpolation=_interp(size[0], cw))
        filled = np.clip(np.rint(back * 255.0), 0, 255).astype(np.uint8)
        out[y0:y1, x0:x1][mask] = filled[mask]
        return out


def _interp(src: int, dst: int) -> int:
    return cv2.INTER_AREA if dst < src else cv2.INTER_CUBIC


def _dynamic_size(w: int, h: int) -> tuple[int, int]:
    s = min(1.0, DYNAMIC_MAX_SIDE / max(w, h))
    return max(32, 32 * math.ceil(w * s / 32)), max(32, 32 * math.ceil(h * s / 32))


def crop_window(region: np.ndarray, model_size: tuple[int, int] | None) -> tuple[int, int, int, int]:
    """Window (x0, y0, x1, y1), half-open, around ``region``'s bounding box with context, shaped
    like ``model_size`` (width, height) where the image allows, so resizing does not distort."""
    ys, xs = np.nonzero(region)
    H, W = region.shape
    bx0, bx1, by0, by1 = int(xs.min()), int(xs.max()) + 1, int(ys.min()), int(ys.max()) + 1
    ctx = max(MIN_CONTEXT_PX, round(CONTEXT_FRACTION * max(bx1 - bx0, by1 - by0)))
    w, h = bx1 - bx0 + 2 * ctx, by1 - by0 + 2 * ctx
    if model_size is not None:  # grow the short side to the model's aspect
        aspect = model_size[0] / model_size[1]
        w, h = max(w, round(h * aspect)), max(h, round(w / aspect))
    w, h = min(w, W), min(h, H)
    cx, cy = (bx0 + bx1) / 2.0, (by0 + by1) / 2.0
    x0 = int(min(max(round(cx - w / 2.0), 0), W - w))
    y0 = int(min(max(round(cy - h / 2.0), 0), H - h))
    return x0, y0, x0 + w, y0 + h
