"""The three test scenes of the 2021 Heidelberg thesis *Ambient Occlusion in 4D*, done right.

The thesis rendered (1) two tetrahedra, (2) a structure of two tetrahedra and (3) cube-like
structures with an indent, and got two things wrong: its occlusion values were stuck at 0 or 1,
and a mirror-symmetric scene rendered asymmetrically. Here every scene exists twice:

* ``raw``: a few open tetrahedra in R^4 (what the thesis rendered). AO is computed at each hit
  point with the hemisphere facing the viewer, which is right for two-sided open geometry.
* ``closed``: true closed 4D surfaces extracted from fields (pentatopes instead of lone
  tetrahedra, indented tesseracts instead of indented 3D cubes).

Every scene is mirror-symmetric about the hyperplane x = 0, and the camera's eye lies in that
hyperplane with its image x axis along world x, so the rendered volume must equal its own flip
along image axis 0 up to Monte Carlo noise (``tests/test_thesis.py`` checks this).

Run ``python -m datasets_gen.thesis --out DIR --size 50``: renders each scene at size^3 without
AO, with AO alone, and with the full illumination model (AO, Lambert, 4D Blinn-Phong
highlights, 4D shadows, colour), writes the volumes (``.vti``) and a side-by-side PNG.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

import ao4d
from ao4d.mesh import SimplexMesh
from ao4d.opencl.cl import BACKENDS
from ao4d.rendering.camera import Camera4D

__all__ = ["raw_scenes", "closed_scenes", "thesis_camera", "render_pair", "render_full", "main", "SCENES"]

SCENES = ("two tetrahedra", "tetrahedra structure", "indented cubes")
# V-shaped walls: w = -SLOPE * |x|, so both walls lean towards the viewer (at -w)
SLOPE = 0.9


def _mirror(vertices: np.ndarray) -> np.ndarray:
    return vertices * np.array([-1.0, 1.0, 1.0, 1.0])


def _wall_tet(gap: float) -> np.ndarray:
    """A tetrahedron in the hyperplane w = SLOPE * x (x <= -gap): a wall of the V."""
    xyz = np.array([[-gap, -0.75, -0.6], [-gap, 0.8, -0.45], [-gap, -0.05, 0.85], [-1.1, 0.0, 0.0]])
    return np.column_stack([xyz, SLOPE * xyz[:, 0]])


def _pair(left: np.ndarray, simplices: np.ndarray) -> SimplexMesh:
    """``left`` and its mirror image as one mesh (mirror orientation reversed to stay consistent)."""
    n = len(left)
    flipped = simplices[:, [1, 0, 2, 3]] + n
    return SimplexMesh(np.vstack([left, _mirror(left)]), np.vstack([simplices, flipped]))


def _indented_grid_tets(centre_x: float) -> tuple[np.ndarray, np.ndarray]:
    """A 3D cube (in the hyperplane w = 0) whose centre vertex is pushed back to w = +0.6.

    A 3x3x3 grid of points over [-0.5, 0.5]^3 around (centre_x, 0, 0), Kuhn-split into 48
    tetrahedra; the middle point moves away from the viewer, making a pit whose walls occlude
    each other.
    """
    axis = np.linspace(-0.5, 0.5, 3)
    pts = np.array(list(itertools.product(axis, axis, axis)))
    pts[:, 0] += centre_x
    w = np.zeros(len(pts))
    w[13] = 0.6  # the centre of the 3x3x3 grid
    index = lambda i, j, k: 9 * i + 3 * j + k  # noqa: E731
    tets = []
    for i, j, k in itertools.product(range(2), repeat=3):
        for perm in itertools.permutations(range(3)):
            corner = np.array([i, j, k])
            chain = [index(*corner)]
            for axis_step in perm:
                corner = corner.copy()
                corner[axis_step] += 1
                chain.append(index(*corner))
            tets.append(chain)
    return np.column_stack([pts, w]), np.array(tets)


def raw_scenes() -> dict[str, SimplexMesh]:
    """The thesis' scenes as a few open tetrahedra in R^4 (mirror-symmetric about x = 0).

    Returns
    -------
    dict of str to SimplexMesh
        ``"two tetrahedra"`` (2 tets, a gap between them), ``"tetrahedra structure"`` (2 tets
        sharing a face: a V-shaped trough) and ``"indented cubes"`` (two cube-like pieces of 48
        tets each with a pit, side by side).
    """
    one = np.array([[0, 1, 2, 3]])
    cube_v, cube_t = _indented_grid_tets(-0.8)
    return {
        "two tetrahedra": _pair(_wall_tet(0.2), one),
        "tetrahedra structure": _pair(_wall_tet(0.0), one),
        "indented cubes": _pair(cube_v, cube_t),
    }


def _pentatope(vertices: np.ndarray):
    """Field of the 4-simplex with these 5 vertices: max over facets of signed plane distance."""
    normals, offsets = [], []
    for k in range(5):
        facet = np.delete(vertices, k, axis=0)
        n = ao4d.geometry.cross(*(facet[1:] - facet[0]))
        n /= np.linalg.norm(n)
        if n @ (vertices[k] - facet[0]) > 0:  # point away from the opposite vertex
            n = -n
        normals.append(n)
        offsets.append(n @ facet[0])
    normals, offsets = np.array(normals), np.array(offsets)
    return lambda p: (np.asarray(p) @ normals.T - offsets).max(axis=-1)


def _thick_wall(gap: float) -> np.ndarray:
    """A pentatope around the wall tetrahedron: its 4 corners plus one pushed back in w."""
    tet = _wall_tet(gap)
    apex = tet.mean(axis=0) + np.array([0.0, 0.0, 0.0, 0.35])
    return np.vstack([tet, apex])


def closed_scenes(grid: int = 24) -> dict[str, list[SimplexMesh]]:
    """The same scenes as closed 4D surfaces extracted from fields (two objects each).

    The right object is the exact mirror image of the extracted left one, so each scene is
    mirror-symmetric to the last bit.

    Parameters
    ----------
    grid : int
        Grid points per axis of each object's box.

    Returns
    -------
    dict of str to list of SimplexMesh
        Left object and its mirror image, extracted on mirror-symmetric grids.
    """
    from ao4d import fields

    def left_and_mirror(field, lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        left = ao4d.extract_field(field, (grid,) * 4, (lo, hi))
        # the exact mirror image (a reflection reverses orientation: swap two vertices)
        right = SimplexMesh(_mirror(left.vertices), left.simplices[:, [1, 0, 2, 3]])
        return [left, right]

    def box_of(vertices, pad=0.15):
        return vertices.min(axis=0) - pad, vertices.max(axis=0) + pad

    gap_penta = _thick_wall(0.2)
    touch_penta = _thick_wall(0.0)
    half, indent = 0.45, 0.3
    # dent on the -w facet (facing the viewer): rotate the +w dent by pi in the (x, w) plane,
    # then move the cube to the left half
    cube = fields.translate(
        fields.rotate(fields.indented_cube(half, indent, axis=3), (0, 3), math.pi), [-0.8, 0.0, 0.0, 0.0]
    )
    return {
        "two tetrahedra": left_and_mirror(_pentatope(gap_penta), *box_of(gap_penta)),
        "tetrahedra structure": left_and_mirror(_pentatope(touch_penta), *box_of(touch_penta)),
        "indented cubes": left_and_mirror(
            cube, [-0.8 - half - 0.15] + [-half - 0.15] * 3, [-0.8 + half + 0.15] + [half + 0.15] * 3
        ),
    }


def thesis_camera() -> Camera4D:
    """Perspective camera in the mirror hyperplane x = 0, looking along +w from above."""
    return Camera4D([0.0, 0.9, -0.6, -4.5], [0.0, 0.0, 0.0, 0.0], [0, 1, 0, 0], [0, 0, 1, 0], fov=36.0)


LIGHT = np.array([0.0, 0.6, -0.3, -1.0])
# the full model: every object in one colour (the scenes stay mirror-symmetric)
FULL = dict(ambient=0.45, diffuse=0.3, specular=0.25, shininess=16.0, shadows=True, color=(1.0, 0.72, 0.42))


def render_pair(meshes, size: int, *, samples: int = 64, seed: int = 0, backend: str = "auto"):
    """Render a scene without AO (Lambert + constant ambient) and with AO at every hit.

    Returns
    -------
    plain, with_ao : RenderResult
        ``plain.shade = 0.5 + 0.5 max(0, n . l)``; ``with_ao.shade = 0.5 (1 - A) + 0.5
        max(0, n . l)``.
    """
    from ao4d.mesh import concatenate

    if not isinstance(meshes, SimplexMesh):  # join once: both renders share one BVH
        meshes = concatenate(meshes)
    cam = thesis_camera()
    shape = (size, size, size)
    common = dict(light=LIGHT, ambient=0.5, diffuse=0.5, backend=backend)
    plain = ao4d.render(meshes, cam, shape, ao="none", **common)
    with_ao = ao4d.render(meshes, cam, shape, ao="hits", samples=samples, seed=seed, **common)
    return plain, with_ao


def render_full(meshes, size: int, *, samples: int = 64, seed: int = 0, backend: str = "auto"):
    """Render a scene with the full illumination model (AO at every hit, lights, shadows, colour).

    Returns
    -------
    RenderResult
        ``shade = 0.5 (1 - A) + V (0.5 max(0, n . l) + 0.35 max(0, n . h)^16)`` with ``V``
        the 4D shadow visibility of :data:`LIGHT` (the AO-alone render is the same without
        the last two factors); ``rgba`` in the colour of :data:`FULL`.
    """
    from ao4d.mesh import concatenate

    if not isinstance(meshes, SimplexMesh):
        meshes = concatenate(meshes)
    return ao4d.render(
        meshes,
        thesis_camera(),
        (size,) * 3,
        ao="hits",
        samples=samples,
        seed=seed,
        light=LIGHT,
        backend=backend,
        **FULL,
    )


def _middle_slice(result) -> int:
    """The z-slice through the centre of the hit voxels (where the objects' middles are)."""
    k = np.nonzero(result.hit)[2]
    return int(round(k.mean())) if k.size else result.hit.shape[2] // 2


def side_by_side_png(path: Path, results: dict, size: int, samples: int) -> Path:
    """One row per scene: raw without AO, with AO, full model; the same closed (middle z-slice)."""
    import matplotlib

    from ao4d.io.pictures import figure, over_background, save_figure

    columns = [
        ("raw", "no AO"),
        ("raw", "AO"),
        ("raw", "full"),
        ("closed", "no AO"),
        ("closed", "AO"),
        ("closed", "full"),
    ]
    index = {"no AO": 0, "AO": 1, "full": 2}
    fig = figure(2.3 * len(columns) + 1.0, 2.3 * len(results) + 0.8)
    grid = fig.add_gridspec(
        len(results),
        len(columns) + 1,
        width_ratios=[1] * len(columns) + [0.07],
        left=0.09,
        right=0.92,
        top=1 - 0.75 / fig.get_figheight(),
        bottom=0.02,
        wspace=0.06,
        hspace=0.18,
    )
    cmap = matplotlib.colormaps["magma"].with_extremes(bad=(0.33, 0.38, 0.45))
    image = None
    for row, (name, variants) in enumerate(results.items()):
        # one crop per row: the hit voxels of all its panels plus a margin of 2 voxels
        seen = np.argwhere(np.any([variants[kind][1].hit.any(axis=2) for kind in ("raw", "closed")], axis=0))
        lo = np.maximum(seen.min(axis=0) - 2, 0) if seen.size else np.zeros(2, int)
        hi = seen.max(axis=0) + 3 if seen.size else np.array(results[name]["raw"][1].hit.shape[:2])
        side = int((hi - lo).max())  # square panels
        hi = lo + side
        crop = (slice(lo[0], hi[0]), slice(lo[1], hi[1]))
        for col, (kind, shading) in enumerate(columns):
            res = variants[kind][index[shading]]
            k = _middle_slice(variants[kind][1])
            ax = fig.add_subplot(grid[row, col])
            if shading == "full":  # the voxels' own colours over the background grey-blue
                colour = over_background(res.rgba[:, :, k])[crop]
                ax.imshow(np.swapaxes(np.clip(colour, 0, 1), 0, 1), origin="lower", interpolation="nearest")
            else:
                data = np.ma.masked_array(res.shade[:, :, k], ~res.hit[:, :, k])[crop]
                image = ax.imshow(data.T, origin="lower", cmap=cmap, vmin=0, vmax=1, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(f"{kind}, {shading}", fontsize=9)
            if col == 0:
                ax.set_ylabel(name, fontsize=9)
    bar = fig.colorbar(image, cax=fig.add_subplot(grid[:, -1]))
    bar.set_label("shade (grey panels)", fontsize=9)
    fig.suptitle(
        f"Thesis scenes redone: {size}^3 images, AO with {samples} rays per voxel "
        "(graded, mirror-symmetric); full: + 4D highlights and shadows, colour",
        fontsize=10,
    )
    return save_figure(fig, path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m datasets_gen.thesis", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--size", type=int, default=50, help="image voxels per axis (default 50)")
    parser.add_argument("--samples", type=int, default=64, help="AO rays per voxel (default 64)")
    parser.add_argument("--grid", type=int, default=24, help="grid points per axis for the closed objects (default 24)")
    parser.add_argument("--backend", choices=BACKENDS, default="auto")
    args = parser.parse_args(argv)
    if args.size < 2 or args.samples < 1 or args.grid < 4:
        parser.error("--size >= 2, --samples >= 1 and --grid >= 4 are required")
    run(args.out, size=args.size, samples=args.samples, grid=args.grid, backend=args.backend)
    return 0


def run(out: Path, *, size: int = 50, samples: int = 64, grid: int = 24, backend: str = "auto", stream=None) -> dict:
    """Render every scene (raw and closed: no AO, AO, full model); write .vti files and a PNG.

    Returns
    -------
    dict
        ``results[scene][kind] = (plain, with_ao, full)`` RenderResults, kind in {"raw",
        "closed"}.
    """
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    raw, closed = raw_scenes(), closed_scenes(grid)
    results: dict = {}
    for name in SCENES:
        results[name] = {}
        for kind, meshes in (("raw", raw[name]), ("closed", closed[name])):
            start = time.perf_counter()
            plain, with_ao = render_pair(meshes, size, samples=samples, backend=backend)
            full = render_full(meshes, size, samples=samples, backend=backend)
            results[name][kind] = (plain, with_ao, full)
            stem = name.replace(" ", "_") + f"_{kind}"
            plain.save(out / f"{stem}_noao.vti")
            with_ao.save(out / f"{stem}_ao.vti")
            full.save(out / f"{stem}_full.vti")
            occ = with_ao.occlusion[with_ao.hit]
            inner = occ[(occ > 0) & (occ < 1)]
            print(
                f"{name:<22}{kind:<8} AO in (0,1) at {inner.size / max(occ.size, 1):.0%} of "
                f"{occ.size} hit voxels, {np.unique(inner).size} distinct values, "
                f"{time.perf_counter() - start:.1f} s",
                file=stream,
                flush=True,
            )
    png = side_by_side_png(out / "thesis_scenes.png", results, size, samples)
    print(f"wrote {png}", file=stream)
    return results


if __name__ == "__main__":
    sys.exit(main())
