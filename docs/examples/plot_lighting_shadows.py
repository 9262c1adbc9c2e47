"""
Lighting and 4D shadows
=======================

:func:`ao4d.render` shades every voxel of the 4D camera's 3D image with

    shade = [ambient (1 − A) + Σ I·V·(diffuse max(0, n·l) + specular max(0, n·h)^shininess)] · cue

all in R⁴: A is the ambient occlusion, l the direction towards a light, h the half-vector of
the light and eye directions, and V is 0 where a 4D shadow ray finds the light blocked.
Here a hypersphere and a torisphere hover over a ground hyperplane, lit by a sun and a warm
point lamp, rendered without and with shadows.
"""

import matplotlib.pyplot as plt
import numpy as np

import ao4d
from ao4d.scenes import box

# %%
# Three small meshes: ground, a hypersphere and a torisphere.
ground = ao4d.extract_field(
    box((-1.6, -0.1, -1.6, -1.6), (1.6, 0.0, 1.6, 1.6)),
    (9, 6, 9, 9),
    [(-1.8, -0.25, -1.8, -1.8), (1.8, 0.15, 1.8, 1.8)],
)
ball = ao4d.extract_field(
    ao4d.fields.hypersphere(0.45, center=(-0.55, 0.75, 0, 0)),
    16,
    [(-1.05, 0.25, -0.5, -0.5), (-0.05, 1.25, 0.5, 0.5)],
)
torus = ao4d.extract_field(
    ao4d.fields.translate(ao4d.fields.torisphere(0.35, 0.15), (0.6, 0.7, 0.0, 0.0)),
    16,
    [(0.05, 0.15, -0.55, -0.55), (1.15, 1.25, 0.55, 0.55)],
)
meshes = [ground, ball, torus]

camera = ao4d.Camera4D(eye=(0, 1.8, -0.8, -5.0), target=(0, 0.5, 0, 0), up=(0, 1, 0, 0), over=(0, 0, 1, 0), fov=40)
sun = ao4d.Light(direction=(-0.35, 1, -0.25, -0.45))
lamp = ao4d.Light(position=(1, 2.5, 0, -1), color=(1, 0.8, 0.6), intensity=0.5)
options = dict(
    light=[sun, lamp],
    ambient=0.25,
    diffuse=0.3,
    specular=0.2,
    shininess=20,
    color=[(0.93, 0.91, 0.85), (0.95, 0.24, 0.17), (0.2, 0.45, 0.9)],
    ao="hits",
    samples=16,
)

# %%
# Render 48³ images without and with 4D shadows.
plain = ao4d.render(meshes, camera, (48, 48, 48), shadows=False, **options)
shadowed = ao4d.render(meshes, camera, (48, 48, 48), shadows=True, **options)
print(f"shadow rays: {shadowed.info['shadow_rays']:,}")
darker = (shadowed.shade < plain.shade - 1e-3).sum()
print(f"voxels darkened by shadows: {darker:,} of {int((plain.depth < np.inf).sum()):,} hit")

# %%
# The middle z-slice of each image, in colour over a white background.
fig, axes = plt.subplots(1, 2, figsize=(8, 4))
for ax, image, title in zip(axes, (plain, shadowed), ("no shadows", "4D shadows")):
    rgba = image.rgba[:, :, 24]
    rgb = rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])
    ax.imshow(np.transpose(rgb, (1, 0, 2)), origin="lower")
    ax.set_title(title)
    ax.set_axis_off()
fig.tight_layout()
plt.show()
