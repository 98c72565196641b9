"""The composite stage: the fused reference render inside the hole, single-image inpainting for what no
reference supplies, merged with a feathered blending map; pixels outside the hole stay the target's.

- :mod:`~geofill.composite.merge`: the blending map and the merge.
- :mod:`~geofill.composite.inpaint`: the single-image inpainters (exemplar, Telea, Navier-Stokes,
  PatchMatch, LaMa).
- :mod:`~geofill.composite.exemplar`: multi-scale exemplar-based completion, the weight-free default.
- :mod:`~geofill.composite.lama`: LaMa through ONNX Runtime, for users who have its weights.
"""
