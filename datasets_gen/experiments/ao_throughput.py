"""AO rays per second versus mesh size: BVH traversal against testing every simplex.

Hyperspheres extracted on finer and finer grids give meshes from a few hundred to ~10^5
tetrahedra. AO is evaluated at a fixed set of vertices (each with its normal), so the number
of rays is the same for every mesh and only the geometry grows. With a BVH the cost per ray
grows about like log(S); brute force grows like S. Two scenes: from the outside of the convex
shell (normals outward) every ray leaves and hits nothing; from the inside (normals flipped)
every ray hits the far side, and any-hit traversal stops at the first hit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._common import best_time, figure, finish_panel, machine, measured, parse_args, save_figure, write_results

NAME = "ao_throughput"


def measure(sizes: Sequence[int], n_points: int, samples: int, brute_max: int, backends, repeats: int) -> list[dict]:
    from ao4d import ambient_occlusion, extract_field, fields

    rows = []
    rng = np.random.default_rng(0)
    for n in sizes:
        mesh = extract_field(fields.hypersphere(1.0), n, (-1.2, 1.2), progress=False)
        pick = rng.choice(mesh.n_vertices, size=min(n_points, mesh.n_vertices), replace=False)
        points, normals = mesh.vertices[pick], mesh.vertex_normals[pick]
        for scene, sign in (("outside (all miss)", 1.0), ("inside (all hit)", -1.0)):
            for backend in backends:
                for accel in ("bvh", "brute"):
                    if accel == "brute" and mesh.n_simplices > brute_max:
                        continue

                    def call():
                        return ambient_occlusion(
                            mesh,
                            points=points,
                            normals=sign * normals,
                            samples=samples,
                            backend=backend,
                            accel=accel,
                            progress=False,
                        )

                    call()  # kernels, BVH and buffers ready before timing
                    seconds, a = best_time(call, repeats)
                    rays = len(points) * samples
                    rows.append(
                        {
                            "grid": n,
                            "simplices": mesh.n_simplices,
                            "scene": scene,
                            "backend": backend,
                            "accel": accel,
                            "rays": rays,
                            "seconds": seconds,
                            "rays_per_second": rays / seconds,
                            "mean_occlusion": float(np.mean(a)),
                        }
                    )
    return rows


def plot(rows: list[dict], path) -> None:
    fig, axes = figure(2)
    for ax, scene in zip(axes, ("outside (all miss)", "inside (all hit)")):
        for backend, colour in (("opencl", "C0"), ("numpy", "C1")):
            for accel, style in (("bvh", "-o"), ("brute", "--s")):
                sel = [r for r in rows if (r["scene"], r["backend"], r["accel"]) == (scene, backend, accel)]
                measured(ax, sel, "simplices", "rays_per_second", style, color=colour, label=f"{backend}, {accel}")
        finish_panel(
            ax,
            title=f"rays from the sphere's vertices, {scene}",
            xlabel="tetrahedra in the mesh",
            ylabel="AO rays per second",
        )
    fig.suptitle(f"4D AO throughput, BVH vs brute force ({machine()})", fontsize=9)
    save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> int:
    from ao4d.opencl import cl

    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    backends = ["opencl"] if cl.get_runtime(warn=False) else ["numpy"]
    if args.quick:
        rows = measure((6, 8), n_points=32, samples=8, brute_max=10**4, backends=backends + ["numpy"], repeats=1)
    else:
        rows = measure(
            (8, 10, 12, 16, 24, 32, 48), n_points=1024, samples=64, brute_max=6 * 10**4, backends=backends, repeats=3
        )
    write_results(args.out, NAME, rows, plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
