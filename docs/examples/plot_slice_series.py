"""
Slicing a 4D mesh into a ParaView time series
=============================================

A 4D surface is a 3D surface that changes along w. Cutting it by the hyperplanes w = const
gives ordinary triangle meshes (:meth:`ao4d.SimplexMesh.slice`, with the mesh's point data
such as AO carried to the cut); ``ao4d slice MESH --w-range A B --count N --out DIR`` writes a
whole sweep as PLY and VTP files plus a ParaView ``series.pvd``, so the sweep plays with
ParaView's time slider.
"""

import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import ao4d
from ao4d.cli import main as ao4d_command

# %%
# A 4D torus (torisphere: a 3-ball swept around a circle) with AO, saved as ao4d's mesh file.
# Its cuts by w = const are ordinary tori whose tube thins as w moves away from 0.
mesh = ao4d.extract_field(ao4d.fields.torisphere(0.8, 0.4), 22, (-1.3, 1.3))
mesh.point_data["ao"] = ao4d.ambient_occlusion(mesh, samples=16)
folder = Path(tempfile.mkdtemp())
mesh.save(folder / "torus.npz")

# %%
# The command line writes the series (the same as running ``ao4d slice`` in a shell).
ao4d_command(
    [
        "slice",
        str(folder / "torus.npz"),
        "--w-range",
        "-0.3",
        "0.3",
        "--count",
        "5",
        "--out",
        str(folder / "series"),
        "--no-progress",
    ]
)
print(sorted(p.name for p in (folder / "series").iterdir()))
print((folder / "series" / "series.pvd").read_text())

# %%
# The same cuts in Python: each is a :class:`trimesh.Trimesh` carrying the AO of the cut edges,
# here coloured from open (purple) to AO 0.5 (yellow).
fig = plt.figure(figsize=(11, 2.8))
for n, w in enumerate(np.linspace(-0.3, 0.3, 5)):
    cut = mesh.slice([0, 0, 0, w], [0, 0, 0, 1])
    ao = cut.vertex_attributes["ao"][cut.faces].mean(axis=1)
    ax = fig.add_subplot(1, 5, n + 1, projection="3d")
    surf = ax.plot_trisurf(*cut.vertices.T, triangles=cut.faces, linewidth=0, antialiased=False)
    surf.set_facecolors(plt.cm.viridis(np.clip(ao / 0.5, 0, 1)))  # AO from 0 (purple) to 0.5
    ax.view_init(elev=35, azim=-60)
    ax.set_title(f"w = {w:+.2f}")
    ax.set_box_aspect((1, 1, 0.4))
    ax.set_axis_off()
fig.tight_layout()
plt.show()

shutil.rmtree(folder)  # the files written above, no longer needed
