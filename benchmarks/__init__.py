"""Benchmark scripts, grouped by what they decide; each runs from the repository root as
``.venv/bin/python benchmarks/<group>/<script>.py`` (``--help`` for its options).

- ``speed/``: time and memory: per stage and size (``speed.py``), the whole process against the
  standalone homography baseline (``whole_process.py``, ``homography_baseline.py``), the renderer,
  the stereo backend, several references, batch throughput and the server.
- ``quality/``: how well this checkout fills and how it copes: ``geofill eval`` against an earlier
  revision (``eval_revisions.py``, ``compare_eval.py``), per-pair pose and stage times, wide
  baselines, the CLI fuzz corpus.
- ``studies/``: the measurements behind a design choice (focal estimation, the optimisation's
  solvers, the depth fit's space and backends, refinement variants, the matching ladder and its
  scales, one focal for several references).
- ``make_results.py``: regenerates docs/results.md by running the scripts above.
- ``common.py``: what the scripts share (where the data is, a git revision's ``src``, the wall time
  and peak RSS of a child process). Scripts put the repository root on ``sys.path`` to import it.
"""
