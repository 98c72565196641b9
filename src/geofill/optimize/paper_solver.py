"""The ``paper`` solver: DiffGrad on the quaternion, t, s, b (and log focal) as published. It needs
autograd, so torch and pytorch-optimizer (the ``paper`` extra) are imported when it runs."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..extras import require
from .objective import objective, project_all
from .params import PoseDepthParams, renormalise
from .problem import LevelLog, Problem


def quaternion_to_matrix(q: Any) -> Any:
    """Rotation matrix (torch) of the quaternion (w, x, y, z), normalised first (differentiable;
    torch has no quaternion type and PyTorch3D's conversion comes with no CPU wheel)."""
    import torch

    w, x, y, z = q / torch.linalg.vector_norm(q)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )


def converged(history: Sequence[float], window: int, eps: float) -> bool:
    """The supplement's convergence test on the objective values ``history`` of one level.

    Its formula is printed with garbled summation bounds; the intended test, implemented here, is the
    relative change between the sum of the last m/2 values and the sum of the m/2 before them:
    ``|sum(l[-m/2:]) - sum(l[-m:-m/2])| / sum(l[-m/2:]) < eps`` (False until m values exist)."""
    if len(history) < window:
        return False
    half = window // 2
    recent = math.fsum(history[-half:])
    previous = math.fsum(history[-window:-half])
    if recent == 0.0:
        return previous == 0.0
    return abs(recent - previous) / abs(recent) < eps


def solve_paper(problem: Problem, init: PoseDepthParams) -> tuple[PoseDepthParams, list[LevelLog]]:
    """DiffGrad on (quaternion, t, s, b[, log focal]) as in the paper: constant learning rate,
    coarse to fine with cumulative iteration limits, the supplement's convergence test, the best
    parameters of each level carried to the next; |t| renormalised at the end (see the module
    docstring)."""
    require("pytorch_optimizer", "the paper solver (optimize.solver=paper)")
    torch = require("torch", "the paper solver (optimize.solver=paper)")
    previous = torch.get_num_threads()
    torch.set_num_threads(max(1, problem.cfg.threads))
    try:
        return _diffgrad(problem.as_torch(), init)
    finally:
        torch.set_num_threads(previous)


def _diffgrad(problem: Problem, init: PoseDepthParams) -> tuple[PoseDepthParams, list[LevelLog]]:
    import torch
    from pytorch_optimizer import DiffGrad  # imports torch.distributed (~2 s): only when used

    cfg = problem.cfg
    f64 = lambda v: torch.tensor(np.asarray(v, np.float64), dtype=torch.float64, requires_grad=True)  # noqa: E731
    q, t, s, b, phi = (
        f64(init.quaternion_wxyz()),
        f64(init.t),
        f64(init.scale),
        f64(init.offset),
        f64(init.log_focal),
    )
    leaves = [q, t, s, b] + ([phi] if cfg.refine_focal else [])
    logs: list[LevelLog] = []
    done = 0
    for k in reversed(range(len(problem.levels))):
        level = problem.levels[k]
        limit = cfg.paper_iterations[len(problem.levels) - 1 - k]
        opt = DiffGrad(leaves, lr=cfg.paper_lr)
        history: list[float] = []
        best_value, best = math.inf, [p.detach().clone() for p in leaves]
        is_conv = False
        while done < limit:
            opt.zero_grad()
            R = quaternion_to_matrix(q).float()
            s32, b32, phi32 = s.float(), b.float(), phi.float()
            xy = project_all(problem, level, R, t.float(), s32, b32, phi32)
            terms = objective(problem, level, *xy, s32, b32, phi32)
            terms.total.backward()
            value = float(terms.total.detach())
            if value < best_value:
                best_value, best = value, [p.detach().clone() for p in leaves]
            opt.step()
            history.append(value)
            done += 1
            if converged(history, cfg.paper_window, cfg.paper_eps):
                is_conv = True
                break
        with torch.no_grad():
            for p, v in zip(leaves, best, strict=True):
                p.copy_(v)
        logs.append(LevelLog(k, len(history), best_value, len(level.points), is_conv))
    with torch.no_grad():
        R = quaternion_to_matrix(q).numpy()
    raw = PoseDepthParams(R, t.detach().numpy().copy(), s.item(), b.item(), phi.item())
    return renormalise(raw, float(np.linalg.norm(init.t)), problem.space), logs
