"""
A 4D interval volume: the shell between two hyperspheres, cut into pentatopes
=============================================================================

:func:`ao4d.extract_solid` fills a region of a 4D grid with pentatopes (4-simplices) instead of
only extracting its boundary. With ``upper=`` the region is an *interval volume*: the points
where ``level <= f < upper``. Here ``f`` is the distance from the origin, so the region between
the levels 0.6 and 1.1 is a thick spherical shell in 4D, with a 4-volume of
``pi^2 / 2 (1.1^4 - 0.6^4)``.

Cutting the solid by the hyperplanes ``w = const`` gives 3D tetrahedral solids
(:meth:`ao4d.SolidMesh.slice`): ball shells whose radii shrink as ``w`` grows, and a solid ball
once ``w`` passes the inner radius. Each cut is written as a ``.vtu`` file (``VTK_TETRA`` cells)
that ParaView opens.
"""

import math
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

import ao4d


def distance(points):
    """The distance from the origin: the 4D field (a callable on (..., 4) points)."""
    return np.linalg.norm(points, axis=-1)


# %%
# Extract the shell on a 13^4 grid, slab by slab, and compare its 4-volume with the analytic one.
# The boundary is a piecewise-linear surface whose facets are chords of the spheres, so the
# outer sphere loses volume and the inner one gains a little: the error falls like the grid
# step squared.
inner, outer = 0.6, 1.1
solid = ao4d.extract_solid_field(distance, (13,) * 4, (-1.2, 1.2), inner, upper=outer, method="simplices")
exact = math.pi**2 / 2 * (outer**4 - inner**4)
print(f"{solid.n_simplices:,} pentatopes; 4-volume {solid.volume:.4f}, analytic {exact:.4f}")
print(f"relative error {solid.volume / exact - 1:+.2%}; boundary volume {solid.boundary().volume:.4f}")
print("conforming and positively oriented:", solid.check().ok)

# %%
# Cut at three values of w. Each cut is a 3D solid of tetrahedra, positively oriented; its
# volume is compared with the 3D shell between the radii ``sqrt(r^2 - w^2)``.
out = Path(tempfile.mkdtemp(prefix="ao4d_interval_"))
ws = (0.0, 0.45, 0.8)
cuts = []
for w in ws:
    cut = solid.slice([0, 0, 0, w], [0, 0, 0, 1])
    r_out = math.sqrt(outer**2 - w**2)
    r_in = math.sqrt(max(inner**2 - w**2, 0.0))
    analytic = 4 / 3 * math.pi * (r_out**3 - r_in**3)
    path = cut.save(out / f"shell_w{w:.2f}.vtu")
    print(f"w = {w:.2f}: {len(cut.tets):,} tets, volume {cut.volume:.4f} (analytic {analytic:.4f}) -> {path.name}")
    cuts.append(cut)

# %%
# Show each cut with its front half (y < 0) removed, so that the hollow inside is visible: the
# boundary triangles of the remaining tetrahedra, drawn with matplotlib.
fig = plt.figure(figsize=(10, 3.6))
for k, (w, cut) in enumerate(zip(ws, cuts)):
    centroids = cut.vertices[cut.tets].mean(axis=1)
    half = ao4d.SolidMesh(cut.vertices, cut.tets[centroids[:, 1] > 0]).boundary()
    ax = fig.add_subplot(1, 3, k + 1, projection="3d")
    tris = half.vertices[half.simplices]
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)  # flat slivers: 0
    shade = 0.35 + 0.65 * np.clip(normals @ np.array([0.3, -0.8, 0.5]), 0, 1)
    ax.add_collection3d(Poly3DCollection(tris, facecolors=plt.cm.viridis(shade), linewidths=0.05, edgecolor="k"))
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-1.1, 1.1)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=20, azim=-60)
    ax.set_title(f"w = {w:.2f}")
    ax.set_axis_off()
fig.suptitle("Cuts of a 4D shell (0.6 <= |x| < 1.1) into tetrahedral solids")
fig.tight_layout()
plt.show()
print("VTU files for ParaView in", out)
