"""Joint optimisation of the relative pose and the depth scale/offset (paper Sec. 3.2, supplement).

Parameters
    Rotation R, translation t (source -> target, ``X_t = R X_s + t``), depth scale s and offset b
    applied in the space of the initial depth fit (``AlignedDepth.space``): the depth used is
    ``s v + b`` where v is the initial aligned depth (``space == "depth"``) or inverse depth
    (``"inverse"``, the default), so s = 1, b = 0 is the initial guess. Optionally a log
    focal scale phi multiplies both images' focal lengths by exp(phi), with a weak prior.

Objective (one function, :func:`objective`, used by both solvers)
    ``l = lambda_photo L_photo + lambda_feat L_feat + lambda_negD L_negD (+ focal prior)``.

    - Reprojection (:func:`project`): every source pixel p with its depth is lifted to 3D, moved into
      the target camera and projected to q_p. The target is sampled bilinearly at q_p, as an
      alpha-premultiplied RGBA image (alpha = 0 in the hole and outside the image), so
      ``d_p = alpha(q_p) I_s(p) - (alpha I_t)(q_p)`` carries no colour from the hole.
    - ``L_photo = 1/|M| sum_p W(q_p) |d_p|^2`` at one level of the Gaussian pyramids of both images,
      |M| the known (non-hole) area of that level (paper Eq. 3). W is the target's importance map
      (:mod:`geofill.optimize.importance`) sampled at q_p: W is defined in the target frame, and sampling it
      where each source pixel lands is the weighting Eq. 3 applies to the warped image.
    - ``L_feat = 1/N sum_m W(q_t^m) f(|reproj(q_s^m) - q_t^m|, alpha, c)``, Barron's general loss
      (alpha = -2, c = 10 px: Geman-McClure), over the pose inliers (Eq. 5).
    - ``L_negD = sum_p max(0, -(s v_p + b))`` over the source pixels of the level (Eq. 6).
    Points with non-positive depth or behind the target camera are moved outside the target, so
    they add no photometric error (and the saturated error to L_feat); L_negD pushes them back.

Coarse to fine
    The paper computes L_photo on the coarsest level first and moves to the next finer level when
    the level has converged (it notes that the multi-scale sum in every iteration would be too
    expensive), so level k's objective uses L_photo of level k only and "the objective" of a
    solution is that of the finest level. Level k has its images, depth and intrinsics downsampled
    by ``cv2.pyrDown`` k times (pixel x of level k+1 is pixel 2x of level k, so f and c halve).

Gauge
    Scaling t and the depth by the same factor changes no projection, so with t as 3 free numbers
    one direction of the problem is flat. The ``paper`` solver optimises the 9 numbers as published
    (quaternion 4, t 3, s, b) and renormalises |t| to its initial length afterwards, adjusting s and
    b so that every projection is unchanged. The ``fast`` solver keeps |t| fixed by moving t on its
    sphere (2 degrees of freedom), which removes the flat direction from its normal equations.

Solvers
    ``paper``: DiffGrad (pytorch_optimizer) with a constant learning rate, cumulative iteration limits
    per level, the supplement's convergence test (:func:`converged`) and the best parameters of each
    level carried to the next. ``fast``: Levenberg-Marquardt on the same objective (exact gradient
    written out, Gauss-Newton / IRLS curvature), on the source pixels whose reprojection lands where
    W is significant, coarse to fine over the same pyramid. Both are followed by the guard rails of
    :func:`guard`.
"""

from .fast_solver import solve_fast
from .importance import importance_map
from .objective import Terms, barron_loss, barron_weight, evaluate, objective
from .paper_solver import converged, quaternion_to_matrix, solve_paper
from .params import (
    Points,
    PoseDepthParams,
    RawGradient,
    array_params,
    project,
    renormalise,
    reprojection_vjp,
)
from .problem import FeatureSet, LevelLog, PhotoLevel, Problem, build_problem, sample_target
from .stage import OptimizationReport, OptimizationResult, fit_space_values, guard, optimize_pose_depth

__all__ = [
    "FeatureSet",
    "LevelLog",
    "OptimizationReport",
    "OptimizationResult",
    "PhotoLevel",
    "Points",
    "PoseDepthParams",
    "Problem",
    "RawGradient",
    "Terms",
    "array_params",
    "barron_loss",
    "barron_weight",
    "build_problem",
    "converged",
    "evaluate",
    "fit_space_values",
    "guard",
    "importance_map",
    "objective",
    "optimize_pose_depth",
    "project",
    "quaternion_to_matrix",
    "renormalise",
    "reprojection_vjp",
    "sample_target",
    "solve_fast",
    "solve_paper",
]
