"""
AO convergence against the analytic slab value
==============================================

A point with normal n at height h under a flat slab that reaches farther sideways than the
ray length D is occluded along exactly the directions within angle t of n where
cos t >= h / D. With cosine-weighted directions this gives, in d dimensions,

.. math:: A = \\left(1 - (h/D)^2\\right)^{(d-1)/2},

so :math:`(1 - (h/D)^2)^{3/2}` in 4D. This example measures the error of
:func:`ao4d.ambient_occlusion` against that value as the number of samples grows. The
directions are a randomly shifted Sobol set, so the error falls about like 1/samples, faster
than the 1/sqrt(samples) of independent rays.
"""

import matplotlib.pyplot as plt
import numpy as np
import trimesh

import ao4d
from ao4d import lift
from ao4d.ao import ORIGIN_OFFSET

HEIGHT, REACH, HALF, THICKNESS = 0.5, 1.0, 1.2, 0.2

# %%
# The slab: a 3D box lifted to a 4D prism between w = HEIGHT and w = HEIGHT + THICKNESS.
roof = lift.prism(trimesh.creation.box(extents=[2 * HALF] * 3), THICKNESS, base=HEIGHT)
print(roof.check())

# %%
# The exact value (rays start a tiny offset above the point, which lowers h by that much).
offset = ORIGIN_OFFSET * float(np.linalg.norm(np.ptp(roof.vertices, axis=0)))
exact = (1 - ((HEIGHT - offset) / REACH) ** 2) ** 1.5
print(f"exact occlusion: {exact:.6f}")

# %%
# 1000 query points at the origin, normal +w: each point gets its own random shift of the
# Sobol set, so their spread is the estimator's error.
points = np.zeros((1000, 4))
normals = np.tile([0.0, 0.0, 0.0, 1.0], (1000, 1))
samples = [4, 8, 16, 32, 64, 128, 256]
rms = []
for s in samples:
    errors = ao4d.ambient_occlusion(roof, points=points, normals=normals, samples=s, max_distance=REACH, seed=s) - exact
    rms.append(float(np.sqrt(np.mean(np.square(errors)))))
    print(f"{s:4d} samples: RMS error {rms[-1]:.4f}")

slope = np.polyfit(np.log(samples), np.log(rms), 1)[0]
print(f"fitted slope of the RMS error: {slope:.2f}")

# %%
fig, ax = plt.subplots(figsize=(5, 3.6))
ax.loglog(samples, rms, "o-", label="ao4d (shifted Sobol)")
binomial = np.sqrt(exact * (1 - exact) / np.array(samples))
ax.loglog(samples, binomial, "--", color="0.5", label="independent rays (expected)")
ax.set_xlabel("samples per point")
ax.set_ylabel("RMS error of A")
ax.legend()
fig.tight_layout()
plt.show()
