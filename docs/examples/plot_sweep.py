"""
4D from motion: a bouncing ball swept through time
==================================================

A 3D shape that moves and deforms traces a solid in space-time: the points ``(x, t)`` with
``x`` inside the shape at time ``t``. :func:`ao4d.lift.sweep` takes frames of one triangle
mesh (same faces, vertices moved) and builds the closed 4D boundary of that solid, time as w:
the first frame as a cap facing -w, the last facing +w, and walls swept by every triangle
from frame to frame (vertices move linearly in between). The result is an ordinary ao4d mesh:
4D ambient occlusion, slices and the browser viewer work on it as on any other.

Here a ball falls, squashes on the floor and bounces back up, in 9 frames over 2 time units.
Time becomes a length (w), so the time scale shapes the 4D solid: a faster bounce makes a
sharper bend in space-time.
"""

import shutil
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import trimesh

import ao4d
from ao4d.cli import main as ao4d_command

# %%
# Nine frames of one icosphere: the centre follows a parabola down to the floor (y = 0) and back,
# and near contact the ball flattens along y and widens along x and z (volume kept: sy sx^2 = 1).
ball = trimesh.creation.icosphere(2, radius=0.5)
times = np.linspace(0.0, 2.0, 9)
frames = []
for t in times:
    sy = 1.0 - 0.4 * np.exp(-(((t - 1.0) / 0.24) ** 2))  # squash at the bounce
    sx = 1.0 / np.sqrt(sy)
    frame = ball.copy()
    frame.apply_scale([sx, sy, sx])
    frame.apply_translation([0.0, 0.5 * sy + 1.2 * (t - 1.0) ** 2, 0.0])  # resting on y = 0 at t = 1
    frames.append(frame)

mesh = ao4d.lift.sweep(frames, times)
report = mesh.check()
print(f"{mesh.n_vertices} vertices, {mesh.n_simplices} tetrahedra, closed and outward: {report.ok}")

# %%
# The enclosed 4-volume is the integral of the ball's volume over time. Between frames that
# volume is a cubic in t, so Simpson's rule on the frames and the slices halfway is exact; the
# squash keeps the volume, so it is close to ``vol(ball) x duration`` as well.
halfway = [mesh.slice([0, 0, 0, (a + b) / 2], [0, 0, 0, 1]).volume for a, b in zip(times, times[1:])]
simpson = sum(
    (b - a) * (f0.volume + 4 * vm + f1.volume) / 6
    for a, b, f0, vm, f1 in zip(times, times[1:], frames, halfway, frames[1:])
)
print(f"4-volume {mesh.volume:.9f}, Simpson on the slices {simpson:.9f}, vol(ball) x 2 = {2 * ball.volume:.9f}")

# %%
# 4D ambient occlusion at the vertices. The space-time tube bends where the ball turns round
# on the floor: the inside of that bend (the top of the ball around t = 1, where it moves down
# and then up again) is occluded.
mesh.point_data["ao"] = ao4d.ambient_occlusion(mesh, samples=32)
print(f"AO from {mesh.point_data['ao'].min():.2f} to {mesh.point_data['ao'].max():.2f}")

# %%
# Slices w = t are the ball at those times, carrying the 4D AO (purple open, yellow AO 0.4 and above).
fig = plt.figure(figsize=(11, 3.2))
shown = [0.4, 0.75, 0.95, 1.0, 1.5]
for n, t in enumerate(shown):
    cut = mesh.slice([0, 0, 0, t], [0, 0, 0, 1])
    ao = cut.vertex_attributes["ao"][cut.faces].mean(axis=1)
    ax = fig.add_subplot(1, len(shown), n + 1, projection="3d")
    x, y, z = cut.vertices.T
    surf = ax.plot_trisurf(x, z, y, triangles=cut.faces, linewidth=0, antialiased=False)  # y up
    surf.set_facecolors(plt.cm.viridis(np.clip(ao / 0.4, 0, 1)))
    ax.set(xlim=(-0.75, 0.75), ylim=(-0.75, 0.75), zlim=(0, 1.6), title=f"t = {t:.2f}")
    ax.view_init(elev=25, azim=-60)
    ax.set_box_aspect((1.5, 1.5, 1.6))
    ax.set_axis_off()
fig.tight_layout()
plt.show()

# %%
# The browser page: drag the w slider to play the bounce (``ao4d.view`` writes one
# self-contained HTML file). On the command line the same sweep is ``ao4d lift sweep FRAMES...
# --times T... --out bounce.npz``, from mesh files such as these PLYs.
folder = Path(tempfile.mkdtemp())
page = ao4d.view(mesh, folder / "bounce.html")
print(f"viewer page: {page.stat().st_size / 1e6:.1f} MB")
for k, frame in enumerate(frames):
    frame.export(folder / f"ball_{k:02d}.ply")
ao4d_command(
    ["lift", "sweep", *sorted(map(str, folder.glob("ball_*.ply"))), "--times-range", "0", "2"]
    + ["--out", str(folder / "bounce.npz"), "--no-progress"]
)

shutil.rmtree(folder)  # the files written above, no longer needed
