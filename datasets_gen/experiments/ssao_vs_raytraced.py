"""Screen-space AO against ray-traced AO at the same hits: error, correlation and time per scene.

Each scene is rendered with the same camera, image, seed and reach: ``ao="hits"`` (64 AO rays
per hit through the BVH), ``ao="screen"`` with the same 64 directions (marched in
:func:`ao4d.rendering.screen_ao.default_steps` points each against the image's own depth volume), and
``ao="screen"`` with 8 directions and ``denoise=1`` (the usual real-time trade). The primary rays
are the same, so all give an occlusion at every hit voxel; the table compares each screen-space
variant with the ray-traced AO there: mean absolute error, Pearson correlation, mean signed
error and the error's histogram.
Times are the best of a few runs taken in turn: the AO stage alone (``info["ao_seconds"]``, what
the speed ratio divides) and the whole render.

Scenes: the demo scene (:func:`ao4d.scenes.default_scene`, its camera, at two reaches), a pair
of interlinked torispheres, and a concave one, a tesseract with a spherical bowl in the facet
that faces the eye.
``ssao_vs_raytraced_steps.csv`` sweeps the march points per direction on the demo scene at both
reaches.

Where screen-space AO is wrong by construction (the figure's second row shows the demo image's
middle z-slice): what the image does not show cannot occlude (the undersides of objects, the
ground under them, anything behind a visible surface or outside the image); every visible
surface is taken as solid up to the reach behind it, so thin objects and silhouettes in front of
distant surfaces cast haloes; and the values depend on the view.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from ._common import machine, parse_args, save_figure, write_results

NAME = "ssao_vs_raytraced"
SAMPLES = 64
REACH = 1.0
STEP_SWEEP = (1, 2, 4, 8, 16)
BINS = np.linspace(-1.0, 1.0, 41)
# screen-space variants: name, directions, denoise radius. The first uses the ray-traced AO's own
# 64 directions (same hits, same directions: only what the depth volume cannot see differs); the
# second is the usual real-time trade, few directions and a depth-aware blur.
SCREEN_VARIANTS = (("screen, 64 directions", SAMPLES, 0), ("screen, 8 directions + denoise", 8, 1))


def scenes(quick: bool) -> list[dict]:
    """The scenes: name, meshes (a list), camera, reach."""
    from ao4d import Camera4D, extract_field, fields
    from ao4d.mesh import concatenate
    from ao4d.scenes import default_scene, extract_scene

    demo = default_scene()
    cell = 0.2 if quick else 0.085
    demo_mesh = concatenate(extract_scene(demo, cell=cell, progress=False))
    n = 24 if quick else 48  # grid points per axis of the other scenes

    big, small = 0.6, 0.22
    ring_a = fields.torisphere(big, small)  # core circle in the xy plane
    ring_b = fields.translate(
        fields.rotate(fields.torisphere(big, small), (1, 2), math.pi / 2), [big, 0, 0, 0]
    )  # in the xz plane, through the first one's hole
    reach = big + small + 0.1
    tori = extract_field(
        fields.union(ring_a, ring_b),
        (n,) * 4,
        ([-reach, -reach, -reach, -small - 0.1], [2 * big + small + 0.1, reach, reach, small + 0.1]),
        progress=False,
    )

    # a tesseract with a spherical bowl in its facet towards the eye (-w): its inside is concave
    bowl_field = fields.difference(fields.tesseract(0.8), fields.hypersphere(0.72, [0, 0, 0, -0.75]))
    bowl = extract_field(bowl_field, (n,) * 4, (-0.95, 0.95), progress=False)

    down = (0.15, -0.3, 0.1, 1.0)
    # the demo's eye at 40 degrees: every scene here renders a cube image, which at that angle
    # frames the objects (the demo's own 62 degrees frame the whole slab in a wide image)
    c = demo.camera
    demo_camera = Camera4D(c.eye, c.target, c.up, c.over, fov=40.0)
    return [
        {"scene": "demo", "mesh": demo_mesh, "camera": demo_camera, "reach": REACH},
        {"scene": "demo (reach inf)", "mesh": demo_mesh, "camera": demo_camera, "reach": math.inf},
        {
            "scene": "torus pair",
            "mesh": tori,
            "camera": Camera4D.framing(tori.bounds, view=(0.2, -0.3, 0.25, 1.0), fov=40),
            "reach": REACH,
        },
        {
            "scene": "bowl (concave)",
            "mesh": bowl,
            "camera": Camera4D.framing(bowl.bounds, view=down, fov=40),
            "reach": REACH,
        },
    ]


def measure(size: int, repeats: int, quick: bool) -> tuple[list[dict], list[dict], dict]:
    from ao4d import render

    rows, hist_rows, slices = [], [], {}
    variants = {"hits": dict(ao="hits", samples=SAMPLES)}
    variants.update({name: dict(ao="screen", samples=n, denoise=r) for name, n, r in SCREEN_VARIANTS})
    for item in scenes(quick):
        mesh, camera, reach = item["mesh"], item["camera"], item["reach"]
        # build kernels, BVH and tables outside the timings
        for kwargs in variants.values():
            render(mesh, camera, (4, 4, 4), max_distance=reach, progress=False, **kwargs)
        timed = {name: [] for name in variants}
        images = {}
        for _ in range(repeats):  # in turn, so that all see the same load
            for name, kwargs in variants.items():
                img = render(
                    mesh, camera, (size,) * 3, max_distance=reach, seed=0, progress=False, max_rays=math.inf, **kwargs
                )
                timed[name].append((img.info["ao_seconds"], img.info["seconds"]))
                images[name] = img
        traced = images["hits"]
        b = traced.occlusion[traced.hit].astype(np.float64)
        ao_t = min(t[0] for t in timed["hits"])
        for name, n_dirs, radius in SCREEN_VARIANTS:
            screen = images[name]
            assert np.array_equal(screen.hit, traced.hit)
            a = screen.occlusion[screen.hit].astype(np.float64)
            err = a - b
            ao_s = min(t[0] for t in timed[name])
            rows.append(
                {
                    "scene": item["scene"],
                    "variant": name,
                    "image": f"{size}^3",
                    "hits": int(screen.hit.sum()),
                    "traced_samples": SAMPLES,
                    "screen_samples": n_dirs,
                    "denoise": radius,
                    "reach": reach,
                    "mae": float(np.abs(err).mean()),
                    "correlation": float(np.corrcoef(a, b)[0, 1]) if a.std() > 0 and b.std() > 0 else float("nan"),
                    "mean_screen": float(a.mean()),
                    "mean_traced": float(b.mean()),
                    "mean_error": float(err.mean()),
                    "rms_error": float(np.sqrt((err**2).mean())),
                    "screen_ao_seconds": ao_s,
                    "traced_ao_seconds": ao_t,
                    "ao_speedup": ao_t / ao_s,
                    "screen_render_seconds": min(t[1] for t in timed[name]),
                    "traced_render_seconds": min(t[1] for t in timed["hits"]),
                    "backend": screen.info["backend"],
                }
            )
            counts, _ = np.histogram(err, BINS)
            for lo, hi, c in zip(BINS[:-1], BINS[1:], counts):
                hist_rows.append(
                    {
                        "scene": item["scene"],
                        "variant": name,
                        "error_lo": float(lo),
                        "error_hi": float(hi),
                        "voxels": int(c),
                        "fraction": float(c / len(err)),
                    }
                )
        if item["scene"] == "demo":
            slices = {"screen": images[SCREEN_VARIANTS[0][0]].occlusion, "traced": traced.occlusion, "hit": traced.hit}
    return rows, hist_rows, slices


def step_sweep(size: int, repeats: int, quick: bool) -> list[dict]:
    """MAE and time of screen-space AO versus march points per direction (demo scene, both
    reaches), with the default of :func:`ao4d.rendering.screen_ao.default_steps` marked."""
    from ao4d import render
    from ao4d.rendering.screen_ao import DepthVolume, default_steps, screen_space_occlusion

    rows = []
    shape = (size,) * 3
    for item in scenes(quick)[:2]:
        mesh, camera, reach = item["mesh"], item["camera"], item["reach"]
        traced = render(
            mesh,
            camera,
            shape,
            ao="hits",
            samples=SAMPLES,
            max_distance=reach,
            seed=0,
            progress=False,
            max_rays=math.inf,
        )
        volume = DepthVolume.trace(mesh, camera, shape)
        hit = volume.hit.reshape(-1)
        origins, directions = (a.reshape(-1, 4) for a in camera.rays(shape))
        points = origins[hit] + volume.depth.reshape(-1)[hit][:, None] * directions[hit]
        normals = volume.normals.reshape(-1, 4)[hit]
        b = traced.occlusion.reshape(-1)[hit].astype(np.float64)
        default = default_steps(volume, reach)
        for steps in STEP_SWEEP:
            best = math.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                a = screen_space_occlusion(
                    volume, points, normals, samples=SAMPLES, max_distance=reach, steps=steps, seed=0
                )
                best = min(best, time.perf_counter() - t0)
            rows.append(
                {
                    "scene": item["scene"],
                    "steps": steps,
                    "default": steps == default,
                    "mae": float(np.abs(a - b).mean()),
                    "correlation": float(np.corrcoef(a, b)[0, 1]),
                    "mean_error": float((a - b).mean()),
                    "seconds": best,
                    "traced_ao_seconds": traced.info["ao_seconds"],
                }
            )
    return rows


def plot_all(rows: list[dict], hist_rows: list[dict], slices: dict, sweep: list[dict], path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13.0, 7.2), dpi=80, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 4)
    scene_names = list(dict.fromkeys(r["scene"] for r in rows))
    _plot_errors(fig.add_subplot(grid[0, 0:2]), rows, hist_rows, scene_names)
    _plot_speed(fig.add_subplot(grid[0, 2]), rows, scene_names)
    _plot_steps(fig.add_subplot(grid[0, 3]), sweep)
    if slices:
        _plot_slices(fig, grid, slices)
    fig.suptitle(
        f"4D screen-space AO vs ray-traced AO ({SAMPLES} rays), {rows[0]['image']} images ({machine()})", fontsize=9
    )
    save_figure(fig, path)


def _plot_errors(ax, rows: list[dict], hist_rows: list[dict], scene_names: list[str]) -> None:
    """Histograms of screen-space minus ray-traced AO per hit voxel, a line per scene and variant."""
    centres = 0.5 * (BINS[:-1] + BINS[1:])
    first = SCREEN_VARIANTS[0][0]
    for r in rows:
        i = scene_names.index(r["scene"])
        style = "-" if r["variant"] == first else ":"
        sel = [h["fraction"] for h in hist_rows if (h["scene"], h["variant"]) == (r["scene"], r["variant"])]
        ax.step(
            centres,
            sel,
            where="mid",
            color=f"C{i}",
            ls=style,
            label=f"{r['scene']}, {r['variant'].split(', ')[1]}: MAE {r['mae']:.3f}, r = {r['correlation']:.2f}",
        )
    ax.set_yscale("log")
    ax.set_xlabel("screen-space AO - ray-traced AO (per hit voxel)")
    ax.set_ylabel("fraction of hit voxels")
    ax.legend(fontsize=6)
    ax.grid(True, alpha=0.3)


def _plot_speed(ax, rows: list[dict], scene_names: list[str]) -> None:
    """AO seconds per scene: ray traced beside each screen-space variant, with the speed-ups."""
    x = np.arange(len(scene_names))
    traced = [next(r for r in rows if r["scene"] == n)["traced_ao_seconds"] for n in scene_names]
    ax.bar(x - 0.27, traced, 0.27, label=f"ray traced, {SAMPLES} rays")
    for k, (name, _, _) in enumerate(SCREEN_VARIANTS):
        sel = [next(r for r in rows if (r["scene"], r["variant"]) == (n, name)) for n in scene_names]
        ax.bar(x + 0.27 * k, [r["screen_ao_seconds"] for r in sel], 0.27, label=name)
        for xi, r in zip(x, sel):
            ax.text(
                xi + 0.27 * k, r["screen_ao_seconds"], f"{r['ao_speedup']:.1f}x", ha="center", va="bottom", fontsize=6
            )
    ax.set_xticks(x, [n.replace(" (", "\n(") for n in scene_names], fontsize=7)
    ax.set_ylabel(f"AO seconds at the same hits ({rows[0]['image']})")
    ax.set_ylim(0, 1.45 * max(traced + [r["screen_ao_seconds"] for r in rows]))
    ax.legend(fontsize=6, loc="upper left")
    ax.set_title("speed-up over ray traced above the bars", fontsize=8)


def _plot_steps(ax, sweep: list[dict]) -> None:
    """MAE against seconds as the march points per direction grow, a line per scene."""
    for i, name in enumerate(dict.fromkeys(r["scene"] for r in sweep)):
        sel = [r for r in sweep if r["scene"] == name]
        ax.plot(
            [r["seconds"] for r in sel],
            [r["mae"] for r in sel],
            "o-",
            color=f"C{i}",
            label=f"{name} (ray traced: {sel[0]['traced_ao_seconds']:.2f} s)",
        )
        for r in sel:
            mark = " (default)" if r["default"] in (True, "True") else ""
            ax.annotate(
                f"{r['steps']}{mark}", (r["seconds"], r["mae"]), fontsize=6, textcoords="offset points", xytext=(3, 3)
            )
    ax.set_xlabel("screen-space AO seconds, 64 directions")
    ax.set_ylabel("MAE against ray traced")
    ax.set_title("march points per direction", fontsize=8)
    ax.legend(fontsize=6)
    ax.grid(True, alpha=0.3)


def _plot_slices(fig, grid, slices: dict) -> None:
    """The demo's z-slice with the largest error: both AOs and their difference, and why they differ."""
    hit = slices["hit"]
    diff = np.where(hit, np.abs(slices["screen"] - slices["traced"]), 0.0)
    k = int(np.argmax(diff.sum(axis=(0, 1))))  # the z-slice with the largest error
    show = lambda a: np.where(hit[:, :, k], a[:, :, k], np.nan).T  # noqa: E731  (x right, y up)
    panels = [
        ("ray-traced AO", slices["traced"], "magma_r", (0, 1)),
        ("screen-space AO", slices["screen"], "magma_r", (0, 1)),
        ("screen - ray traced", slices["screen"] - slices["traced"], "RdBu_r", (-0.3, 0.3)),
    ]
    for j, (title, arr, cmap, (vmin, vmax)) in enumerate(panels):
        ax = fig.add_subplot(grid[1, j])
        im = ax.imshow(show(arr), origin="lower", cmap=cmap, vmin=vmin, vmax=vmax)
        ax.set_title(f"demo, z-slice {k}: {title}", fontsize=8)  # screen: 64 directions
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8)
    ax = fig.add_subplot(grid[1, 3])
    ax.axis("off")
    ax.text(
        0,
        1,
        "Wrong by construction\n(blue: too open, red: too occluded)\n\n"
        "- occluders the image does not\n"
        "  show: the ground under objects,\n"
        "  their hidden backs, anything\n"
        "  outside the image: too open\n"
        "- a visible surface is taken as\n"
        "  solid up to the reach behind\n"
        "  it: haloes on what lies behind\n"
        "  silhouettes and thin objects\n"
        "- march points leaving the\n"
        "  image count as open",
        va="top",
        fontsize=8,
        family="monospace",
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(NAME, __doc__.splitlines()[0], argv)
    size, repeats = (16, 1) if args.quick else (80, 3)
    rows, hist_rows, slices = measure(size, repeats, args.quick)
    sweep = step_sweep(size, repeats, args.quick)
    write_results(
        args.out,
        NAME,
        rows,
        lambda r, p: plot_all(r, hist_rows, slices, sweep, p),
        {"histogram": hist_rows, "steps": sweep},
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
