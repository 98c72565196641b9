"""A depth or disparity map supplied by the user (phone LiDAR / portrait depth, stereo, GT)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import DepthFileError
from ..io import read_depth_file
from . import DepthContext, DepthPrediction


class FileDepth:
    name = "file"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        cfg = ctx.cfg
        if not cfg.file_path:
            raise DepthFileError("depth backend 'file' needs a depth file (--depth-file PATH)")
        values = read_depth_file(cfg.file_path, expected_size=ctx.source_size_px, scale=cfg.file_scale)
        h, w = ctx.source.shape[:2]
        if values.shape != (h, w):
            # Nearest keeps depth edges sharp and NaN (invalid) pixels from bleeding into valid ones.
            values = cv2.resize(values, (w, h), interpolation=cv2.INTER_NEAREST)
        space = "depth" if cfg.file_kind == "depth" else "inverse"
        metric = cfg.file_metric and cfg.file_kind == "depth"
        return DepthPrediction(values.astype(np.float32), space, self.name, metric=metric)
