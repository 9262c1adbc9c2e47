"""Experiments behind the README's tables and figures; each writes ``NAME.csv`` and ``NAME.png``.

Run one with ``python -m datasets_gen.experiments.NAME --out DIR [--quick]``:

- ``extraction_error``: volume and boundary-measure error of extracted meshes against analytic
  values, versus grid size, for both extraction methods.
- ``ao_convergence``: AO error and time versus samples per point against the exact occlusion
  under a flat roof, in 3D and 4D.
- ``ao_throughput``: AO rays per second versus mesh size, BVH versus brute force.
- ``extract_throughput``: extraction cells per second, ao4d versus scikit-image's marching cubes
  (3D), and ao4d alone in 4D.
- ``ssao_vs_raytraced``: 4D screen-space AO against ray-traced AO at the same hits (error,
  correlation, histogram and time per scene).

``--quick`` runs a small version (seconds) with the same code path; the figures in
``docs/experiments/`` come from full runs.
"""

NAMES = ("extraction_error", "ao_convergence", "ao_throughput", "extract_throughput", "ssao_vs_raytraced")
