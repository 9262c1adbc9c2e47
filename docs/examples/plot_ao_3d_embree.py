"""
3D ambient occlusion against Embree
===================================

ao4d's stages work in 2, 3 and 4 dimensions, so that each can be checked against trusted 3D
tools. Here a 3D isosurface made by scikit-image's marching cubes gets ambient occlusion from
:func:`ao4d.ambient_occlusion`, and the very same rays are traced by Intel's Embree (through
trimesh) to compare.
"""

import matplotlib.pyplot as plt
import numpy as np
from skimage.measure import marching_cubes

import ao4d
from ao4d import bvh, sampling
from ao4d.ao import ORIGIN_OFFSET

# %%
# Two blobs over a floor, as one 3D signed-distance field on a 48³ grid.
x, y, z = np.meshgrid(*[np.linspace(-1.2, 1.2, 48)] * 3, indexing="ij")
blobs = np.minimum(
    np.sqrt((x + 0.35) ** 2 + y**2 + z**2) - 0.45, np.sqrt((x - 0.45) ** 2 + (y + 0.2) ** 2 + z**2) - 0.35
)
floor = np.maximum.reduce([np.abs(z + 0.65) - 0.1, np.abs(x) - 1.0, np.abs(y) - 1.0])
field = np.minimum(blobs, floor)
spacing = (2.4 / 47,) * 3
verts, faces, normals, _ = marching_cubes(field, 0.0, spacing=spacing)
verts -= 1.2
mesh = ao4d.SimplexMesh(verts, faces)
print(mesh.check())

# %%
# AO at 300 vertices, 64 cosine-weighted directions each.
rng = np.random.default_rng(0)
idx = rng.choice(mesh.n_vertices, 300, replace=False)
points, point_normals = mesh.vertices[idx], mesh.vertex_normals[idx]
ours = ao4d.ambient_occlusion(mesh, points=points, normals=point_normals, samples=64)

# %%
# The same directions and ray origins, traced by Embree when it is installed.
try:
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector
except ImportError:  # embreex is installed with ao4d on x86-64 only
    RayMeshIntersector = None

directions = sampling.cosine_hemisphere(point_normals, 64).reshape(-1, 3)
offset = ORIGIN_OFFSET * bvh.get_bvh(mesh).world_diagonal
origins = np.repeat(points + offset * point_normals, 64, axis=0)
if RayMeshIntersector is not None:
    scene = trimesh.Trimesh(mesh.vertices, mesh.simplices, process=False)
    theirs = RayMeshIntersector(scene).intersects_any(origins, directions)
    theirs = theirs.reshape(-1, 64).mean(axis=1)
    print(
        f"largest difference per point: {np.abs(ours - theirs).max():.4f} "
        f"(one ray of 64 is {1 / 64:.4f}); mean {ours.mean():.4f} vs {theirs.mean():.4f}"
    )
else:
    theirs = None
    print("embreex is not installed: Embree's side is left out")

# %%
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(9, 3.8))
if theirs is not None:
    ax0.plot([0, 1], [0, 1], color="0.7")
    ax0.scatter(theirs, ours, s=8)
    ax0.set_xlabel("Embree (trimesh + embreex)")
ax0.set_ylabel("ao4d")
ax0.set_title("AO at the same 300 points")
sc = ax1.scatter(points[:, 0], points[:, 1], c=ours, cmap="magma", s=10, vmin=0, vmax=1)
ax1.set_aspect("equal")
ax1.set_title("AO seen from above (x, y)")
fig.colorbar(sc, ax=ax1, label="occlusion")
fig.tight_layout()
plt.show()
