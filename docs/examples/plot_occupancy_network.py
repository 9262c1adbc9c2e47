"""
Learning 4D occupancy from a dataset
====================================

An occupancy network answers one question: is this 4D point inside the shape? This example
makes a small :mod:`datasets_gen` dataset of randomly rotated and sized 4D shapes with learning
samples and a train/test split, trains a shape-conditioned occupancy network on it in PyTorch
(on the CPU, about a minute on two cores), scores it on the test split, and extracts the
learned 4D surface of a test shape with ao4d, shaded by its ambient occlusion, beside the true
one.

A plain MLP from a 4D point to occupancy cannot tell the shapes apart: on randomly rotated
shapes it learns their average blob (on this dataset a test IoU of about 0.2, below the fixed
ball of the baseline below). The network is therefore told which shape it is asked about: a
PointNet encoder (one MLP shared by all of the shape's surface points, then a max over the
points) turns the item's surface samples into a code, and the decoder reads a query point
concatenated with that code.
"""

import shutil
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import torch
from torch import nn

import ao4d
import datasets_gen
from datasets_gen.transforms import SubsamplePoints

torch.manual_seed(0)
torch.set_num_threads(2)

# %%
# The dataset
# -----------
# Three families, each shape randomly rotated in 4D and randomly sized: hyperspheres,
# torispheres (a ball swept around a circle: a 4D torus with a hole) and rounded tesseracts.
# ``samples`` gives every item labelled points (uniform in its box, then near its surface) and
# points on its surface with normals; ``split`` deals the items into train and test.
config = {
    "name": "occupancy",
    "seed": 0,
    "split": {"train": 0.75, "test": 0.25},
    "defaults": {
        "grid": 24,
        "rotation": "random",
        "ao": {"samples": 16},
        "samples": {"uniform": 2048, "near_surface": 2048, "sigmas": [0.05], "surface": 1024},
    },
    "family": [
        {"kind": "hypersphere", "count": 24, "params": {"radius": {"uniform": [0.4, 1.0]}}},
        {"kind": "torisphere", "count": 24, "params": {"R": {"uniform": [0.5, 0.9]}, "r": {"uniform": [0.2, 0.35]}}},
        {"kind": "tesseract", "count": 24, "params": {"half": {"uniform": [0.3, 0.7]}, "rounding": 0.05}},
    ],
}
folder = Path(tempfile.mkdtemp())
start = time.perf_counter()
# workers=2 spawns processes, which re-import the script: a plain script then needs its calls
# under ``if __name__ == "__main__":``. One process keeps this example runnable as it is.
print(datasets_gen.run(config, folder / "data", workers=1, progress=False))
print(f"made in {time.perf_counter() - start:.0f} s")

# %%
# Training data
# -------------
# Only the arrays the network reads, as float32. ``datasets_gen.transforms.SubsamplePoints``
# picks a fixed number of rows of each item, new ones every epoch (``set_epoch``), so that
# PyTorch's default collate stacks a batch.
keys = ("points", "occupancy", "surface_points", "surface_normals")
train = datasets_gen.load(
    folder / "data", split="train", keys=keys, dtype="float32", transform=SubsamplePoints(points=1024, surface=256)
)
test = datasets_gen.load(folder / "data", split="test", keys=(*keys, "record"), dtype="float32")
loader = torch.utils.data.DataLoader(train, batch_size=6, shuffle=True, generator=torch.Generator().manual_seed(0))
print(f"{len(train)} training items, {len(test)} test items")


# %%
# The network
# -----------
# The encoder reads each surface point with its normal (8 numbers); the max over the points
# makes the code independent of their order and number. The decoder's output is a logit:
# positive inside.
class OccupancyNetwork(nn.Module):
    def __init__(self, code=128, hidden=128):
        super().__init__()
        self.encoder = nn.Sequential(nn.Linear(8, 64), nn.ReLU(), nn.Linear(64, 128), nn.ReLU(), nn.Linear(128, code))
        self.decoder = nn.Sequential(
            nn.Linear(4 + code, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, 1),
        )

    def encode(self, surface_points, surface_normals):  # (..., M, 4) each -> (..., code)
        return self.encoder(torch.cat([surface_points, surface_normals], -1)).max(dim=-2).values

    def forward(self, points, code):  # (..., N, 4), (..., code) -> (..., N) logits
        code = code[..., None, :].expand(*points.shape[:-1], code.shape[-1])
        return self.decoder(torch.cat([points, code], -1))[..., 0]


def random_rotations(n):
    """``n`` rotation matrices, uniform in SO(4)."""
    q, r = torch.linalg.qr(torch.randn(n, 4, 4))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1))[:, None, :]
    q[:, :, 0] *= torch.linalg.det(q)[:, None]
    return q


# %%
# Training
# --------
# Binary cross-entropy on the occupancy labels. Each batch is also turned by a random 4D
# rotation, the query points and the surface samples together: the same shape in another
# pose, so that 54 shapes teach the network about every orientation.
model = OccupancyNetwork()
epochs = 150
optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, epochs * len(loader))
losses = []
start = time.perf_counter()
for epoch in range(epochs):
    train.set_epoch(epoch)  # other rows of every item
    total = 0.0
    for batch in loader:
        turn = random_rotations(len(batch["points"]))
        points, surface, normals = (batch[k] @ turn for k in ("points", "surface_points", "surface_normals"))
        logits = model(points, model.encode(surface, normals))
        loss = nn.functional.binary_cross_entropy_with_logits(logits, batch["occupancy"].float())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        schedule.step()
        total += loss.item()
    losses.append(total / len(loader))
    if epoch % 30 == 0 or epoch == epochs - 1:
        print(f"epoch {epoch:3d}: loss {losses[-1]:.3f}")
print(f"trained in {time.perf_counter() - start:.0f} s")


# %%
# Test IoU, against a trivial baseline
# ------------------------------------
# IoU (intersection over union of the predicted and true inside) on each test item's uniform
# points, averaged over the items. The baseline knows nothing about the shape: it predicts
# the ball about the origin whose radius gives the best mean IoU on the training items.
def iou(predicted, true):
    return (predicted & true).sum() / max((predicted | true).sum(), 1)


def uniform_rows(item):
    return slice(*item["record"]["samples"]["rows"]["uniform"])


def predict(item, points):
    with torch.no_grad():
        code = model.encode(torch.from_numpy(item["surface_points"]), torch.from_numpy(item["surface_normals"]))
        return model(torch.from_numpy(np.asarray(points, np.float32)), code).numpy()


model.eval()
radii = np.linspace(0.05, 1.5, 59)
labelled = datasets_gen.load(folder / "data", split="train", keys=("points", "occupancy", "record"))
ball_iou = np.zeros(len(radii))
for item in labelled:
    rows = uniform_rows(item)
    distance = np.linalg.norm(item["points"][rows], axis=1)
    ball_iou += [iou(distance < r, item["occupancy"][rows]) for r in radii]
radius = radii[np.argmax(ball_iou)]

scores, baseline, kinds = [], [], []
for item in test:
    rows = uniform_rows(item)
    points, inside = item["points"][rows], item["occupancy"][rows]
    scores.append(iou(predict(item, points) > 0, inside))
    baseline.append(iou(np.linalg.norm(points, axis=1) < radius, inside))
    kinds.append(item["record"]["kind"])
for kind in dict.fromkeys(kinds):
    mine = [s for s, k in zip(scores, kinds) if k == kind]
    print(f"{kind}: IoU {np.mean(mine):.2f} over {len(mine)} test items")
print(f"baseline: the ball of radius {radius:.3f}")
print(f"test IoU: {np.mean(scores):.2f} (baseline {np.mean(baseline):.2f})")

# %%
# The training loss.
fig, ax = plt.subplots(figsize=(5.5, 3.2))
ax.plot(losses)
ax.set_xlabel("epoch")
ax.set_ylabel("binary cross-entropy")
ax.set_yscale("log")
fig.tight_layout()
plt.show()

# %%
# The learned 4D surface
# ----------------------
# The network's field for one test torisphere, with the code of its surface samples, is
# sampled on a grid over the item's box and its level set extracted as a closed 4D mesh. ao4d's
# solid is ``{f < 0}`` (negative inside), so the field is minus the logit.
index = kinds.index("torisphere")
item = test[index]
lo, hi = np.asarray(item["record"]["grid"]["bounds"])
lo, hi = lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo)  # room for a surface a little too large


def learned_field(x):
    return -predict(item, np.reshape(x, (-1, 4))).reshape(np.shape(x)[:-1]).astype(np.float64)


learned = ao4d.extract_field(learned_field, (24, 24, 24, 24), (lo, hi))
learned.point_data["ao"] = ao4d.ambient_occlusion(learned, samples=32)
stored = datasets_gen.load(folder / "data", split="test")[index]  # with its mesh and AO
truth = ao4d.SimplexMesh(stored["vertices"], stored["simplices"])
truth.point_data["ao"] = stored["ao"]
print(f"item {item['index']}: R = {item['record']['params']['R']:.2f}, r = {item['record']['params']['r']:.2f}")
for name, mesh in (("true", truth), ("learned", learned)):
    print(
        f"{name}: {mesh.n_simplices} tetrahedra, 4-volume {mesh.volume:.3f}, mean AO {mesh.point_data['ao'].mean():.3f}"
    )

# %%
# 3D slices of both by hyperplanes w = const, w along the shape's own w axis (across the
# torus' circle): each is a 3D ring torus. AO from 0 (purple) to 0.3 (yellow). The slices are
# ordinary triangle meshes (:meth:`ao4d.SimplexMesh.slice`) in the hyperplane's own
# coordinates, the same for both meshes.
rotation = np.asarray(item["record"]["rotation"])
normal = rotation @ np.array([0.0, 0.0, 0.0, 1.0])  # the shape's own w axis, rotated with it
offsets = (-0.25, 0.0, 0.25)
fig = plt.figure(figsize=(10, 6.2))
for row, (name, mesh) in enumerate((("true", truth), ("learned", learned))):
    for col, offset in enumerate(offsets):
        cut = mesh.slice(offset * normal, normal)
        ax = fig.add_subplot(2, 3, 3 * row + col + 1, projection="3d")
        if len(cut.faces):
            ao = cut.vertex_attributes["ao"][cut.faces].mean(axis=1)
            surf = ax.plot_trisurf(*cut.vertices.T, triangles=cut.faces, linewidth=0, antialiased=False)
            surf.set_facecolors(plt.cm.viridis(np.clip(ao / 0.3, 0, 1)))
        ax.set_xlim(-1, 1)
        ax.set_ylim(-1, 1)
        ax.set_zlim(-1, 1)
        ax.view_init(elev=30, azim=-60)
        ax.set_axis_off()
        ax.set_title(f"{name}, w = {offset:+.2f}")
fig.tight_layout()
plt.show()

shutil.rmtree(folder)  # the dataset written above, no longer needed

# sphinx_gallery_thumbnail_number = 2
