"""
A 4D NIfTI volume: closed surfaces and axis units
=================================================

Real 4D data is often a 3D scan over time, stored as NIfTI. Two things matter when ao4d makes a
4D surface of it:

* an object that touches the edge of the grid (here: the first and last time frames) is cut
  open there; ``closed=True`` closes it with caps on the grid's boundary;
* the time axis is not a length. :func:`ao4d.read_grid` reads the header's units and, unless
  told otherwise, takes one frame as one mean x/y/z step (a note says so); ``w_scale=`` sets
  the length per time unit instead.

This example writes a small synthetic scan (a bright ball that moves and grows over eight
frames) with nibabel, reads it back and extracts it both ways.
"""

import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import nibabel as nib
import numpy as np

import ao4d

# %%
# A 16³ × 8 int16 scan, 2 mm voxels, 250 ms per frame: intensity 1000 inside the ball.
i, j, k, t = np.meshgrid(*(np.arange(n) for n in (16, 16, 16, 8)), indexing="ij")
centre = 6.0 + 0.5 * t
radius = 4.0 + 0.25 * t
data = np.where((i - centre) ** 2 + (j - 7.5) ** 2 + (k - 7.5) ** 2 < radius**2, 1000, 0)
image = nib.Nifti1Image(data.astype(np.int16), np.diag([2.0, 2.0, 2.0, 1.0]))
image.header.set_xyzt_units("mm", "msec")
image.header["pixdim"][4] = 250.0
folder = Path(tempfile.mkdtemp())
nib.save(image, folder / "scan_4d.nii.gz")

# %%
# Read it: spacing and units come from the header, the time axis gets a length scale.
grid = ao4d.read_grid(folder / "scan_4d.nii.gz")
print("units:", grid.units)
print("spacing:", grid.spacing)
for note in grid.notes:
    print("note:", note)

# %%
# The same scan with an explicit scale: 1 mm per 100 ms, i.e. a w step of 2.5 mm.
scaled = ao4d.read_grid(folder / "scan_4d.nii.gz", w_scale=0.01)
print("spacing with w_scale=0.01:", scaled.spacing)

# %%
# The ball is bright, so the solid is ``inside="above"`` the level. It exists in the first
# and last frames, so the plain surface is open at the grid's edge; ``closed=True`` closes it.
kwargs = dict(spacing=scaled.spacing, origin=scaled.origin, inside="above")
open_mesh = ao4d.extract(scaled.values, 500, **kwargs)
closed_mesh = ao4d.extract(scaled.values, 500, closed=True, **kwargs)
print("closed=False:", open_mesh.check().closed, f"({open_mesh.n_simplices} tetrahedra)")
print("closed=True: ", closed_mesh.check().closed, f"({closed_mesh.n_simplices} tetrahedra)")
print(f"4-volume of the closed solid: {closed_mesh.volume:.0f} mm⁴")

# %%
# Slices of the closed 4D surface at three times (w = t · 0.01 mm/ms): 3D surfaces of the ball.
fig = plt.figure(figsize=(10, 3.4))
for n, frame in enumerate((1, 4, 6)):
    w = scaled.origin[3] + frame * scaled.spacing[3]
    cut = closed_mesh.slice([0, 0, 0, w], [0, 0, 0, 1])
    ax = fig.add_subplot(1, 3, n + 1, projection="3d")
    ax.plot_trisurf(*cut.vertices.T, triangles=cut.faces, color="C1", linewidth=0)
    ax.set_title(f"frame {frame} (w = {w:.2f} mm)")
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlim(0, 30)
    ax.set_ylim(0, 30)
    ax.set_zlim(0, 30)
fig.tight_layout()
plt.show()

shutil.rmtree(folder)  # the files written above, no longer needed
