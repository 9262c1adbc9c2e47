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
# Read it back: with ``datasets_gen.load`` where this version has it, else from the files.
if hasattr(datasets_gen, "load"):
    dataset = datasets_gen.load(folder / "data")
    items = [dataset[i] for i in range(len(dataset))]
    records = [item["record"] for item in items]
else:
    records = [json.loads(p.read_text()) for p in sorted((folder / "data" / "items").glob("*/record.json"))]
items_dir = folder / "data" / "items"
meshes = [ao4d.SimplexMesh.load(p) for p in sorted(items_dir.glob("*/mesh.npz"))]
aos = [np.load(p)["occlusion"] for p in sorted(items_dir.glob("*/ao.npz"))]
for record, mesh in zip(records, meshes):
    print(f"item {record['index']}: {record['kind']}, {mesh.n_simplices} tetrahedra, closed: {mesh.check().closed}")
manifest = json.loads((folder / "data" / "manifest.json").read_text())
print(f"manifest: {manifest['n_items']} items, {len(manifest['files'])} files hashed")

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
