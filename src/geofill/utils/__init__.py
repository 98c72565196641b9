"""Numerical and resolution helpers shared by the stages: none of them is a stage of its own.

- :mod:`~geofill.utils.distance`: exact Euclidean distance transform (SciPy's answer, faster).
- :mod:`~geofill.utils.jit`: numba kernels compiled on first use, started in the background.
- :mod:`~geofill.utils.membrane`: membrane (Laplace) interpolation of scattered values.
- :mod:`~geofill.utils.numerics`: robust losses, robust least squares, bounded 1-D minimisation.
- :mod:`~geofill.utils.resolution`: sizes in px at the 1280-px reference converted to an image's scale.
- :mod:`~geofill.utils.residual_flow`: the refinement's residual optical flow.
- :mod:`~geofill.utils.rotations`: SO(3) and S² helpers (skew matrices, left Jacobian, tangent bases).
- :mod:`~geofill.utils.windows`: the window round the hole a stage works in.
"""
