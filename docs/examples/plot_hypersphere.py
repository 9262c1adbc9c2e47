"""
A hypersphere: field, surface, ambient occlusion, image
=======================================================

The whole pipeline in a few lines: sample a signed-distance field on a 4D grid, extract its
true 4D surface (a closed tetrahedral mesh), compute 4D ambient occlusion at its vertices,
and render it through a 4D camera into a 3D image volume.

A hypersphere alone has no occlusion at all (every point sees an open half-space), so a ground
hyperplane is added under it: the AO then darkens where the two meet.
"""

import matplotlib.pyplot as plt
import numpy as np

import ao4d

# %%
# Extract the surfaces. ``extract_field`` samples each field on the grid slab by slab; the
# ground is a thin 4D box (:func:`ao4d.scenes.box` gives its signed distance).
ball = ao4d.extract_field(
    ao4d.fields.hypersphere(0.6, center=(0, 0.62, 0, 0)),
    20,
    [(-0.7, -0.05, -0.7, -0.7), (0.7, 1.35, 0.7, 0.7)],
)
ground = ao4d.extract_field(
    ao4d.scenes.box((-1.2, -0.1, -1.2, -1.2), (1.2, 0.0, 1.2, 1.2)),
    (10, 5, 10, 10),
    [(-1.4, -0.3, -1.4, -1.4), (1.4, 0.2, 1.4, 1.4)],
)
for name, mesh in [("ball", ball), ("ground", ground)]:
    report = mesh.check()
    print(f"{name}: {mesh.n_simplices} tetrahedra, closed={report.closed}, 4-volume {mesh.volume:.4f}")
print(f"the exact 4-volume of the ball: {np.pi**2 / 2 * 0.6**4:.4f}")

# %%
# 4D ambient occlusion of both meshes together: 1 = fully occluded, 0 = open.
scene = ao4d.mesh.concatenate([ground, ball])
ao = ao4d.ambient_occlusion(scene, samples=32)
ground.point_data["ao"] = ao[: ground.n_vertices]
ball.point_data["ao"] = ao[ground.n_vertices :]
print(f"AO on the ball: min {ball.point_data['ao'].min():.2f}, max {ball.point_data['ao'].max():.2f}")

# %%
# Render a 32³ image volume: a 4D camera looks along +w, and its screen is a 3D grid of voxels.
camera = ao4d.Camera4D(eye=(0, 1.2, -0.4, -4.5), target=(0, 0.4, 0, 0), up=(0, 1, 0, 0), over=(0, 0, 1, 0), fov=40)
image = ao4d.render(
    [ground, ball], camera, shape=(32, 32, 32), ao="vertices", light=(0, 1, 0, -1), ambient=0.8, diffuse=0.2
)
print(image.shade.shape, image.shade.dtype)

# %%
# Four z-slices of the image volume (the voxel shade, white where no surface was hit).
fig, axes = plt.subplots(1, 4, figsize=(10, 2.8))
for ax, k in zip(axes, (8, 13, 18, 23)):
    ax.imshow(
        np.where(image.depth[:, :, k] < np.inf, image.shade[:, :, k], 1.0).T,
        origin="lower",
        cmap="gray",
        vmin=0,
        vmax=1,
    )
    ax.set_title(f"z-slice {k}")
    ax.set_axis_off()
fig.tight_layout()
plt.show()

# %%
# The whole image volume seen from outside, as the demo's volume picture draws it
# (:func:`ao4d.io.pictures.surface_view`: the hit voxels' smoothed outer surface in their shade).
hit = np.isfinite(image.depth)
colours = plt.cm.magma(np.where(hit, image.shade, 0.0))[..., :3]
geometry = image.geometry
picture, shown, extent, _ = ao4d.io.pictures.surface_view(
    hit, colours, spacing=geometry.spacing, origin=geometry.origin, width=400
)
fig, ax = plt.subplots(figsize=(5, 4))
ax.imshow(np.where(shown[..., None], picture, 1.0), extent=extent)
ax.set_title("the 32³ image volume, coloured by shade")
ax.set_axis_off()
fig.tight_layout()
plt.show()

# sphinx_gallery_thumbnail_number = 2
