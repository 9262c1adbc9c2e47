"""Benchmarks of ao4d against its peers, run from the repository root as ``python -m bench.NAME``.

``bench._protocol`` is the protocol every script follows (machine line, load gate, rounds taken
in turn, median and min–max spreads); ``bench._shapes`` the 4D shapes the AO benchmarks trace;
``bench._embree`` the peer (Embree through Open3D in a process of its own, or trimesh).
"""
