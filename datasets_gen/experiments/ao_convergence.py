"""AO error and time versus samples per point, against the exact occlusion under a flat roof.

A point p with normal n sits at height h below a flat slab (a 4D prism of a 3D box, or a 3D box)
that reaches farther sideways than the ray length D. A ray at angle t from n hits the slab's
underside at distance h / cos t, so it counts when cos t >= h / D. Projecting the
cosine-weighted hemisphere onto the tangent space gives the uniform measure on the unit
(d-1)-ball (Nusselt's analogy, in d dimensions), and the occluded directions project onto the
ball of radius sin t_max = sqrt(1 - (h/D)^2), hence exactly

    A = (1 - (h / D)^2)^((d - 1) / 2)       (3D: 1 - (h/D)^2;  4D: (1 - (h/D)^2)^(3/2)).

Each ray occludes or not, so s independent rays would give a binomial mean with standard
deviation sqrt(A (1 - A) / s). ao4d's directions are a randomly shifted Sobol set
(:mod:`ao4d.sampling`), so its RMS error over many points (each with its own shift) falls faster;
the figure shows both, and ``ao_convergence_fit.csv`` the fitted slope of the RMS error
(about -1 here, against -1/2 for independent rays).
Rays start ORIGIN_OFFSET bounding-box diagonals above p, so h is reduced by that offset.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from ._common import figure, machine, measured, parse_args, save_figure, write_results

NAME = "ao_convergence"
HEIGHT, REACH, HALF_WIDTH, THICKNESS = 0.5, 1.0, 1.2, 0.2


def roof(dim: int):
    """A slab covering |x_i| <= HALF_WIDTH (i < d-1) between heights HEIGHT and HEIGHT+THICKNESS."""
    import trimesh

    from ao4d import SimplexMesh, lift

    if dim == 3:
        box = trimesh.creation.box(
            bounds=[[-HALF_WIDTH, -HALF_WIDTH, HEIGHT], [HALF_WIDTH, HALF_WIDTH, HEIGHT + THICKNESS]]
        )
        return SimplexMesh(box.vertices, box.faces)
    box = trimesh.creation.box(extents=[2 * HALF_WIDTH] * 3)
    return lift.prism(box, THICKNESS, base=HEIGHT)


def exact_occlusion(dim: int, mesh) -> float:
    """The closed form above, with the ray-origin offset taken off the height."""
    from ao4d.ao import ORIGIN_OFFSET

    offset = ORIGIN_OFFSET * float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
    return (1.0 - ((HEIGHT - offset) / REACH) ** 2) ** ((dim - 1) / 2)


def measure(samples: Sequence[int], n_points: int, numpy_max_rays: int) -> list[dict]:
    from ao4d import ambient_occlusion
    from ao4d.opencl import cl

    backends = ["numpy"] + (["opencl"] if cl.get_runtime(warn=False) else [])
    rows = []
    for dim in (3, 4):
        mesh = roof(dim)
        exact = exact_occlusion(dim, mesh)
        points = np.zeros((n_points, dim))
        normals = np.zeros((n_points, dim))
        normals[:, -1] = 1.0
        for backend in backends:
            ambient_occlusion(
                mesh, points=points[:1], normals=normals[:1], samples=1, max_distance=REACH, backend=backend
            )  # build kernels and BVH
            for s in samples:
                if backend == "numpy" and n_points * s > numpy_max_rays:
                    continue
                t0 = time.perf_counter()
                a = ambient_occlusion(
                    mesh,
                    points=points,
                    normals=normals,
                    samples=s,
                    max_distance=REACH,
                    seed=s,
                    backend=backend,
                    progress=False,
                )
                seconds = time.perf_counter() - t0
                rows.append(
                    {
                        "dim": dim,
                        "backend": backend,
                        "samples": s,
                        "points": n_points,
                        "exact": exact,
                        "mean": float(a.mean()),
                        "bias": float(a.mean() - exact),
                        "rms_error": float(np.sqrt(np.mean((a - exact) ** 2))),
                        "rms_theory": math.sqrt(exact * (1 - exact) / s),
                        "seconds": seconds,
                        "rays_per_second": n_points * s / seconds,
                    }
                )
    return rows


def fit_slopes(rows: list[dict], min_samples: int = 16) -> list[dict]:
    """Least-squares slope of log(RMS error) against log(samples), from ``min_samples`` on."""
    out = []
    for dim in sorted({r["dim"] for r in rows}):
        for backend in sorted({r["backend"] for r in rows}):
            sel = [r for r in rows if (r["dim"], r["backend"]) == (dim, backend) and r["samples"] >= min_samples]
            if len(sel) >= 2:
                slope = np.polyfit(np.log([r["samples"] for r in sel]), np.log([r["rms_error"] for r in sel]), 1)[0]
                out.append(
                    {
                        "dim": dim,
                        "backend": backend,
                        "from_samples": min_samples,
                        "to_samples": sel[-1]["samples"],
                        "slope": float(slope),
                    }
                )
    return out


def plot(rows: list[dict], path) -> None:
    fig, (ax_e, ax_t) = figure(2)
    slopes = {(f["dim"], f["backend"]): f["slope"] for f in fit_slopes(rows)}
    for dim, colour in ((3, "C0"), (4, "C1")):
        backend = rows[-1]["backend"]
        sel = [r for r in rows if r["dim"] == dim and r["backend"] == backend]
        s = np.array([r["samples"] for r in sel])
        slope = slopes.get((dim, backend))
        fitted = "" if slope is None else f", slope {slope:.2f}"
        ax_e.loglog(
            s,
            [r["rms_error"] for r in sel],
            "o",
            color=colour,
            label=f"{dim}D measured (exact A = {sel[0]['exact']:.4f}{fitted})",
        )
        ax_e.loglog(s, [r["rms_theory"] for r in sel], "-", color=colour, label=f"{dim}D binomial sqrt(A(1-A)/s)")
        for backend, style in (("opencl", "-o"), ("numpy", "--s")):
            sb = [r for r in rows if r["dim"] == dim and r["backend"] == backend]
            measured(ax_t, sb, "samples", "seconds", style, color=colour, label=f"{dim}D, {backend}")
    ax_e.set_xlabel("samples per point s")
    ax_e.set_ylabel("RMS error of A over the points")
    ax_e.legend(fontsize=7)
    ax_t.set_xlabel("samples per point s")
    ax_t.set_ylabel(f"seconds for {rows[0]['points']} points")
    ax_t.legend(fontsize=7)
    for ax in (ax_e, ax_t):
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"AO under a flat roof, h/D = {HEIGHT / REACH:g} ({machine()})", fontsize=9)
    save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    if args.quick:
        rows = measure((1, 4, 16, 64), n_points=64, numpy_max_rays=4096)
    else:
        rows = measure((1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 4096), n_points=2048, numpy_max_rays=1 << 19)
    write_results(args.out, NAME, rows, plot, {"fit": fit_slopes(rows)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
