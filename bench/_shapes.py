"""The 4D shapes the AO benchmarks trace (``bench.ao``, ``bench.cast``, ``bench.ao_accuracy``).

The spheritorus, the tiger, the ditorus, a CSG of tesseracts (deep concavities), and two with
dense mutual occlusion: three interlocked 4D tori around a ball (``tori``) and a cluster of 40 4D
metaballs (``metaballs``); :func:`shape_mesh` extracts one with about a given number of
tetrahedra.
"""

from __future__ import annotations

import math

import numpy as np

SHAPES = ("spheritorus", "tiger", "ditorus", "csg", "tori", "metaballs")
DENSE = ("tori", "metaballs")  # dense mutual occlusion: Embree also traces their 3D analogues


def csg_field():
    """A tesseract of half side 1 with four pockets: tesseracts of half side 0.5 turned by 30
    degrees in four planes and sunk halfway into the facets +x, +y, +z and -w (deep concavities
    whose walls occlude each other)."""
    import ao4d

    fields = ao4d.fields
    pockets = []
    for axis, sign, plane in ((0, 1, (1, 2)), (1, 1, (2, 3)), (2, 1, (0, 3)), (3, -1, (0, 1))):
        centre = np.zeros(4)
        centre[axis] = sign * 1.0
        cube = fields.rotate(fields.tesseract(0.5, 0.05), plane, math.radians(30))
        pockets.append(fields.translate(cube, centre))
    return fields.difference(fields.tesseract(1.0, 0.05), fields.union(*pockets))


def tori_field():
    """Three interlocked 4D tori around a ball: torispheres (a circle of radius 0.9 swept by a
    3-ball of radius 0.28) whose core circles lie in the xy plane, the zw plane and a plane
    turned between them, united with a hypersphere of radius 0.6 at their common centre."""
    import ao4d

    fields = ao4d.fields

    def torus():
        return fields.torisphere(0.9, 0.28)

    second = fields.rotate(fields.rotate(torus(), (0, 2), math.pi / 2), (1, 3), math.pi / 2)
    third = fields.rotate(fields.rotate(torus(), (1, 2), math.pi / 2), (0, 3), math.pi / 4)
    return fields.union(fields.hypersphere(0.6), torus(), second, third)


def metaballs_field():
    """A cluster of 40 4D metaballs of radius 0.3 (sharpness 8) at random centres in
    [-0.8, 0.8]^4 (seed 3): narrow crevices between the balls."""
    import ao4d

    centres = np.random.default_rng(3).uniform(-0.8, 0.8, size=(40, 4))
    return ao4d.fields.metaballs(centres, 0.3, sharpness=8.0)


def shape_mesh(name: str, tets: float):
    """A 4D shape extracted with about ``tets`` tetrahedra (grid spacing from a first estimate)."""
    import ao4d

    if name == "spheritorus":
        field = ao4d.fields.spheritorus(1.0, 0.4)
        # the tet count grows like n^3 (a 3-manifold); n = 48 gives about 1.1M
        n = max(8, round(48 * (tets / 1.1e6) ** (1 / 3)))
        shape = (n, n, n, max(6, n // 3))
        return ao4d.extract_field(field, shape, ((-1.5, -1.5, -1.5, -0.5), (1.5, 1.5, 1.5, 0.5)))
    if name == "csg":
        field, lo, hi = csg_field(), np.full(4, -1.0), np.full(4, 1.0)
    else:
        field = {
            "tiger": ao4d.fields.tiger,
            "ditorus": ao4d.fields.ditorus,
            "tori": tori_field,
            "metaballs": metaballs_field,
        }[name]()
        lo, hi = np.asarray(field.extent[0], float), np.asarray(field.extent[1], float)
    pad = 0.1 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    spacing = 0.1
    probe = ao4d.extract_field(field, tuple(np.maximum(8, np.round((hi - lo) / spacing).astype(int))), (lo, hi))
    spacing *= (probe.n_simplices / tets) ** (1 / 3)
    shape = tuple(int(k) for k in np.maximum(8, np.round((hi - lo) / spacing)))
    return ao4d.extract_field(field, shape, (lo, hi))
