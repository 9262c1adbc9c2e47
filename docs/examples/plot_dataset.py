"""
A dataset, made and loaded
==========================

:mod:`datasets_gen` makes reproducible procedural 4D datasets: for each item the closed 4D
mesh, its ambient occlusion and a JSON record (parameters, the item's seed, versions, the
mesh check, the volume against the analytic value), plus a ``manifest.json`` of sha256 hashes.
The same configuration and seed give byte-identical files, and an interrupted run resumes.

This example writes a configuration of four tiny items, makes the dataset, and reads it back.
"""

import json
import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import ao4d
import datasets_gen

# %%
# A configuration names shape families and the distributions of their parameters.
folder = Path(tempfile.mkdtemp())
(folder / "tiny.toml").write_text("""
name = "tiny"
seed = 7

[defaults]
grid = 14
rotation = "random"
ao = { samples = 8 }

[[family]]
kind = "spheritorus"
count = 2
params = { R = { uniform = [0.6, 0.8] }, r = { uniform = [0.25, 0.35] } }

[[family]]
kind = "hypersphere"
count = 2
params = { radius = { uniform = [0.5, 0.9] } }
""")

# %%
# Make it (``python -m datasets_gen tiny.toml --out DIR`` does the same).
summary = datasets_gen.run(folder / "tiny.toml", folder / "data", progress=False)
print(summary)

# %%
# Read it back with :func:`datasets_gen.load`: each item is a dict of its arrays (the mesh's
# ``vertices`` and ``simplices``, the ``ao`` of its vertices) and its ``record``.
dataset = datasets_gen.load(folder / "data")
items = [dataset[i] for i in range(len(dataset))]
meshes = [ao4d.SimplexMesh(item["vertices"], item["simplices"]) for item in items]
aos = [item["ao"] for item in items]
for item, mesh in zip(items, meshes):
    record = item["record"]
    print(f"item {record['index']}: {record['kind']}, {mesh.n_simplices} tetrahedra, closed: {mesh.check().closed}")
manifest = json.loads((folder / "data" / "manifest.json").read_text())
print(f"manifest: {manifest['n_items']} items, {len(manifest['files'])} files hashed")

# %%
# Each item cut through its centre across its own x axis (the record's ``rotation`` turned the
# shape): a spheritorus gives a ring torus, a hypersphere a ball. AO from 0 (purple) to 0.3.
fig = plt.figure(figsize=(10, 2.8))
for n, (item, mesh, ao) in enumerate(zip(items, meshes, aos)):
    mesh.point_data["ao"] = ao
    normal = np.asarray(item["record"]["rotation"]) @ [1.0, 0.0, 0.0, 0.0]
    cut = mesh.slice(np.zeros(4), normal)
    ax = fig.add_subplot(1, len(items), n + 1, projection="3d")
    surf = ax.plot_trisurf(*cut.vertices.T, triangles=cut.faces, linewidth=0, antialiased=False)
    surf.set_facecolors(plt.cm.viridis(np.clip(cut.vertex_attributes["ao"][cut.faces].mean(axis=1) / 0.3, 0, 1)))
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()
    ax.set_title(f"item {n}: {item['record']['kind']}")
fig.tight_layout()
plt.show()

# %%
# The distribution of AO over each item's vertices.
fig, ax = plt.subplots(figsize=(5.5, 3.4))
for n, ao in enumerate(aos):
    ax.hist(ao, bins=20, range=(0, 1), histtype="step", label=f"item {n}")
ax.set_xlabel("ambient occlusion at a vertex")
ax.set_ylabel("vertices")
ax.legend()
fig.tight_layout()
plt.show()

shutil.rmtree(folder)  # the files written above, no longer needed

# sphinx_gallery_thumbnail_number = 1
