"""One item of a dataset: its seeds, its folder, how it is made and when it is complete.

An item's files live in ``items/<index:05d>/`` of the run's :class:`~datasets_gen._store.Store`::

    mesh.npz      the closed 4D mesh (ao4d.io.mesh_files npz layout: SimplexMesh.load reads it)
    ao.npz        occlusion per vertex (or per simplex), float64
    <render>.png  optional renders (z-slice montage of the shaded 3D image)
    samples.npz   optional learning samples (datasets_gen.samples)
    sequence.npz  optional 3D frames along an axis (datasets_gen.sequence)
    timing.json   wall-clock seconds per stage (not hashed)
    record.json   parameters, seeds, versions, mesh check, measures, file hashes; written last

Item ``i`` draws everything from ``np.random.SeedSequence([seed, i])`` (:func:`item_seed`), so
items can be made in any order or process and give the same bytes. Every file is written
through the store, each atomically, and ``record.json`` last: an item is complete when its
record exists and every file it lists has the recorded hash (:func:`item_complete`).

Remaking an item removes only the files a run writes there (:func:`own_file`: the names above
and the hidden temporary files of atomic writes); anything else in the folder (notes, a
user's extra files) is left as it is (:func:`foreign_files` lists them for a warning).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ao4d._npz import npz_bytes

from ._files import json_bytes, written_bytes
from ._store import Store, open_store
from .config import ItemSpec, sample_params

__all__ = [
    "RUN_FORMAT",
    "ITEM_FILES",
    "Job",
    "item_seed",
    "item_folder",
    "item_complete",
    "own_file",
    "foreign_files",
    "make_item",
    "resolved_backend",
    "write_item",
    "versions",
]

RUN_FORMAT = 1
#: the files an item may hold besides its renders (``<render name>.png``)
ITEM_FILES = frozenset({"mesh.npz", "ao.npz", "samples.npz", "sequence.npz", "record.json", "timing.json"})


def own_file(name: str, renders: Iterable[str] = ()) -> bool:
    """Whether ``name`` in an item's folder is a file a run writes (and may replace or remove).

    Parameters
    ----------
    name : str
        A file name in the item's folder.
    renders : iterable of str
        The names of the configuration's renders (each writes ``<name>.png``).

    Returns
    -------
    bool
        True for :data:`ITEM_FILES`, the renders' PNGs, and the hidden temporary files of their
        atomic writes (``.<name>.<random>.tmp...``); False for anything else.
    """
    own = ITEM_FILES | {f"{r}.png" for r in renders}
    if name in own:
        return True
    if name.startswith(".") and ".tmp" in name:  # ao4d._atomic and the stores: .<target>.<hex>.tmp<ext>
        return any(name.startswith(f".{target}.") for target in own)
    return False


def foreign_files(store: Store, index: int, renders: Iterable[str] = ()) -> list[str]:
    """The files in item ``index``'s folder that no run writes (:func:`own_file`), sorted.

    Parameters
    ----------
    store : Store
        The run's output.
    index : int
        The item's index.
    renders : iterable of str
        The names of the configuration's renders.

    Returns
    -------
    list of str
        Names relative to the item's folder; a rerun leaves them as they are.
    """
    renders = list(renders)
    return [name for name in store.files(item_folder(index)) if not own_file(name, renders)]


@dataclass(frozen=True)
class Job:
    """What a process needs to make one item.

    Attributes
    ----------
    spec : ItemSpec
        The item: its index, family and number in the family.
    seed : int
        The run's seed.
    out : str
        The run's output (a folder or an fsspec URL), as the process making the item sees it.
    backend : {"opencl", "numpy"}
        The backend that computes the AO, the renders and the samples' rays: the config's
        resolved once per run (:func:`resolved_backend`).
    run_sha256 : str
        sha256 of the output's ``run.json``: a process that reads the same sees the same output.
    split : str, optional
        The item's split (:mod:`datasets_gen.splits`), None without a split table.
    """

    spec: ItemSpec
    seed: int
    out: str
    backend: str
    run_sha256: str = ""
    split: str | None = None


def item_seed(seed: int, index: int) -> np.random.SeedSequence:
    """The seed sequence of item ``index`` of a run with ``seed``.

    Parameters
    ----------
    seed : int
        The run's seed.
    index : int
        The item's index.

    Returns
    -------
    numpy.random.SeedSequence
        ``SeedSequence([seed, index])``: everything random about the item is drawn from it.
    """
    return np.random.SeedSequence([int(seed), int(index)])


def item_folder(index: int) -> str:
    """The folder of item ``index`` in its run's store (``"items/00003"``).

    Parameters
    ----------
    index : int
        The item's index.

    Returns
    -------
    str
        A relative POSIX path.
    """
    return f"items/{int(index):05d}"


def item_complete(store: Store, index: int) -> bool:
    """Whether item ``index`` of ``store`` is complete.

    Parameters
    ----------
    store : Store
        The run's output.
    index : int
        The item's index.

    Returns
    -------
    bool
        True when its ``record.json`` exists and every file it lists has the recorded hash.
    """
    rel = item_folder(index)
    try:
        files = json.loads(store.read_text(f"{rel}/record.json"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return all(
        store.is_file(f"{rel}/{name}") and store.sha256(f"{rel}/{name}") == digest for name, digest in files.items()
    )


def write_item(store: Store, index: int, files: Mapping[str, bytes]) -> None:
    """Write a made item's files into ``store``: leftovers of an interrupted attempt deleted
    first, each file atomically, ``record.json`` last (it marks the item complete).

    Only the run's own files are deleted (:func:`own_file`, the renders being the PNGs among
    ``files``); any other file in the folder is left as it is.

    Parameters
    ----------
    store, index
        As for :func:`item_complete`.
    files : mapping of str to bytes
        File name -> bytes, as :func:`make_item` wrote them into another store.
    """
    rel = item_folder(index)
    renders = [name[:-4] for name in files if name.endswith(".png")]
    for stale in store.files(rel):
        if stale not in files and own_file(stale, renders):
            store.remove(f"{rel}/{stale}")
    store.remove(f"{rel}/record.json")
    for name in sorted(files, key=lambda n: n == "record.json"):
        store.write_bytes(f"{rel}/{name}", files[name])


def versions() -> dict[str, str]:
    """ao4d's version and the checksums of its lookup tables and kernel sources.

    Returns
    -------
    dict of str to str
        ``ao4d``, ``kernels_sha256``, ``lut_manifest_sha256``, ``lut_cube_4d_sha256`` and
        ``lut_simplex_4d_sha256``: the same values give the same items.
    """
    import ao4d
    from ao4d._resources import data_dir

    manifest = data_dir("lut") / "manifest.json"
    manifest_bytes = manifest.read_bytes()
    tables = json.loads(manifest_bytes.decode("utf-8")).get("files", {})
    kernels = hashlib.sha256()
    for path in sorted(data_dir("kernels").iterdir()):
        if path.suffix in (".cl", ".h"):
            kernels.update(path.name.encode() + b"\0" + path.read_bytes())
    return {
        "ao4d": ao4d.__version__,
        "kernels_sha256": kernels.hexdigest(),
        "lut_manifest_sha256": hashlib.sha256(manifest_bytes).hexdigest(),
        "lut_cube_4d_sha256": tables.get("cube_4d.npz", {}).get("sha256", ""),
        "lut_simplex_4d_sha256": tables.get("simplex_4d.npz", {}).get("sha256", ""),
    }


@contextlib.contextmanager
def _stage(timing: dict[str, float], name: str) -> Iterator[None]:
    """Add the wall-clock seconds of the ``with`` block to ``timing[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timing[name] = timing.get(name, 0.0) + time.perf_counter() - t0


class _Writer:
    """Writes an item's files into its folder of a store and keeps their hashes."""

    def __init__(self, store: Store, index: int, timing: dict[str, float], renders: Iterable[str] = ()) -> None:
        self.store, self.rel, self.timing = store, item_folder(index), timing
        self.hashes: dict[str, str] = {}
        renders = list(renders)
        for stale in store.files(self.rel):  # leftovers of an interrupted attempt (no valid record)
            if own_file(stale, renders):  # never a file the run did not write (a user's notes)
                store.remove(f"{self.rel}/{stale}")

    def __call__(self, name: str, data: bytes) -> None:
        """Write a file of the item, timed as ``write``, and keep its hash for the record."""
        with _stage(self.timing, "write"):
            self.store.write_bytes(f"{self.rel}/{name}", data)
            self.hashes[name] = hashlib.sha256(data).hexdigest()

    def npz(self, name: str, arrays: dict[str, Any]) -> None:
        """Write ``arrays`` as the ``.npz`` file ``name`` of the item; packing them is timed as
        ``write`` too."""
        with _stage(self.timing, "write"):
            data = npz_bytes(arrays)
        self(name, data)

    def close(self, timing: bytes, record: bytes) -> None:
        """Write ``timing.json`` and then ``record.json``, which marks the item complete
        (neither is hashed in the record nor timed: the timing is already complete)."""
        self.store.write_bytes(f"{self.rel}/timing.json", timing)
        self.store.write_bytes(f"{self.rel}/record.json", record)


def make_item(job: Job, store: Store | None = None) -> dict[str, Any]:
    """Make item ``job.spec.index`` and write its files into ``store``.

    Top-level and given only picklable arguments: it runs in spawned processes and on dask
    workers alike. ``timing.json`` holds the wall-clock seconds of each stage: ``build``
    (field, grid and extraction, or the lifted solid), ``check`` (mesh check, volume,
    measure), ``bvh`` (the tree the AO rays and the renders trace), ``ao``, ``render_<name>``
    (primary rays, AO at hits, shading) and ``picture_<name>`` (the PNG) per render,
    ``samples`` and ``sequence`` (the labelled points and the frames, when the config asks),
    ``write`` (every file and hash), and ``total``.

    Parameters
    ----------
    job : Job
        The item and its run.
    store : Store, optional
        Where to write; default the store of ``job.out``.

    Returns
    -------
    dict
        ``{"index": index, "seconds": {stage: seconds}}``.
    """
    start = time.perf_counter()
    spec = job.spec
    store = open_store(job.out) if store is None else store
    timing: dict[str, float] = {}
    settings = spec.family.settings
    write = _Writer(store, spec.index, timing, [r["name"] for r in settings["renders"]])
    draw = _Draw.of(job)
    made = _build(job, draw, timing, write)
    if settings["ao"] or settings["renders"]:
        with _stage(timing, "bvh"):
            _build_bvh(made.shape.mesh, job.backend)
    occlusion = _occlusion(made.shape.mesh, settings, draw.ao_seed, job.backend, timing, write)
    extra = _learning(job, draw, made.shape, occlusion, timing, write)
    for render in settings["renders"]:
        title = f"item {spec.index}: {spec.family.name} ({spec.family.kind}), looking along +w"
        png = _render(render, made.shape.mesh, occlusion, settings, draw.ao_seed, job.backend, title, timing)
        write(f"{render['name']}.png", png)
    with _stage(timing, "write"):
        record = _record(job, draw, made, occlusion, dict(write.hashes), extra)
    timing["total"] = time.perf_counter() - start
    write.close(json_bytes({"seconds": timing, "pid": os.getpid()}), json_bytes(record))
    return {"index": spec.index, "seconds": timing}


@dataclass(frozen=True)
class _Draw:
    """What item ``job.spec.index`` draws from its seed: its parameters, rotation and AO seed,
    and the generators of its builder, samples and frames."""

    params: dict[str, Any]
    rotation: np.ndarray | None
    ao_seed: int
    rng: np.random.Generator  # the builder's, after the parameters were drawn from it
    samples_ss: np.random.SeedSequence
    sequence_ss: np.random.SeedSequence

    @classmethod
    def of(cls, job: Job) -> _Draw:
        from .families import random_rotation

        # spawn(5)'s first three children are spawn(3)'s: samples left the meshes, AO and renders as they were
        params_ss, rotation_ss, ao_ss, samples_ss, sequence_ss = item_seed(job.seed, job.spec.index).spawn(5)
        rng = np.random.default_rng(params_ss)
        params = sample_params(job.spec.family.params, rng)
        random = job.spec.family.settings["rotation"] == "random"
        rotation = random_rotation(np.random.default_rng(rotation_ss)) if random else None
        return cls(params, rotation, int(ao_ss.generate_state(1)[0]), rng, samples_ss, sequence_ss)


@dataclass(frozen=True)
class _Built:
    """An item's shape and what its check measured."""

    shape: Any  # datasets_gen.families.Shape
    report: Any  # ao4d.topology.MeshReport
    volume: float
    measure: float


def _build(job: Job, draw: _Draw, timing: dict[str, float], write: _Writer) -> _Built:
    """Build the item's mesh, check and measure it, and write ``mesh.npz``."""
    from .families import build_shape

    with _stage(timing, "build"):
        shape = build_shape(job.spec.family.kind, draw.params, job.spec.family.settings, draw.rng, draw.rotation)
    mesh = shape.mesh
    with _stage(timing, "check"):
        report = mesh.check()
        volume, measure = float(mesh.volume), float(mesh.measure)
    with _stage(timing, "write"):
        data = written_bytes("mesh.npz", mesh.save)
    write("mesh.npz", data)
    return _Built(shape, report, volume, measure)


def _occlusion(
    mesh: Any, settings: dict, seed: int, backend: str, timing: dict[str, float], write: _Writer
) -> np.ndarray | None:
    """The item's occlusion (written as ``ao.npz``), or None when the config asks for none."""
    if not settings["ao"]:
        return None
    import ao4d

    ao = settings["ao"]
    with _stage(timing, "ao"):
        # ao.tolerance (with confidence, max_samples) instead of samples: the config allows one
        accuracy = {k: ao[k] for k in ("tolerance", "confidence", "max_samples") if k in ao}
        occlusion, error = ao4d.ambient_occlusion(
            mesh,
            samples=64 if accuracy else ao["samples"],
            max_distance=ao["max_distance"],
            at=ao["at"],
            seed=seed,
            backend=backend,
            progress=False,
            return_error=True,
            **accuracy,
        )
    arrays = {"occlusion": np.asarray(occlusion, np.float64)}
    if accuracy:  # the standard errors of a tolerance's values
        arrays["error"] = np.asarray(error, np.float64)
    write.npz("ao.npz", arrays)
    return occlusion


def _learning(
    job: Job, draw: _Draw, shape: Any, occlusion: Any, timing: dict[str, float], write: _Writer
) -> dict[str, Any]:
    """The learning samples and the frames the config asks for (``samples.npz``,
    ``sequence.npz``), and their entries of the record."""
    settings, kind = job.spec.family.settings, job.spec.family.kind
    extra: dict[str, Any] = {}
    ao_at = settings["ao"]["at"] if settings["ao"] else "vertices"
    inputs = dict(occlusion=occlusion, ao_at=ao_at, backend=job.backend)
    if settings.get("samples"):
        from .samples import make_samples

        with _stage(timing, "samples"):
            rng = np.random.default_rng(draw.samples_ss)
            arrays, extra["samples"] = make_samples(shape, kind, settings["samples"], rng, **inputs)
        write.npz("samples.npz", arrays)
    if settings.get("sequence"):
        from .sequence import make_sequence

        with _stage(timing, "sequence"):
            arrays, extra["sequence"] = make_sequence(
                shape,
                kind,
                settings["sequence"],
                samples=settings.get("samples") or None,
                rng=np.random.default_rng(draw.sequence_ss),
                **inputs,
            )
        write.npz("sequence.npz", arrays)
    return extra


def _record(
    job: Job, draw: _Draw, made: _Built, occlusion: Any, files: dict[str, str], extra: dict[str, Any]
) -> dict[str, Any]:
    """The item's ``record.json``: what it is, how it was made, what it measures, its files' hashes."""
    from .samples import normalization

    spec, settings, shape, mesh = job.spec, job.spec.family.settings, made.shape, made.shape.mesh
    expected = shape.volume_expected
    return {
        "format": RUN_FORMAT,
        "index": spec.index,
        "family": spec.family.name,
        "kind": spec.family.kind,
        "number": spec.number,
        "seed": {"run": job.seed, "entropy": [job.seed, spec.index], "ao": draw.ao_seed},
        "params": draw.params,
        "derived": shape.derived,
        "rotation": draw.rotation,
        "settings": {k: v for k, v in settings.items() if k != "renders"},
        "renders": settings["renders"],
        "grid": shape.grid,
        "versions": versions(),
        "mesh": {
            "vertices": mesh.n_vertices,
            "simplices": mesh.n_simplices,
            "check": {**asdict(made.report), "ok": made.report.ok},
            "volume": made.volume,
            "measure": made.measure,
            "volume_expected": expected,
            "volume_rel_error": None if not expected else made.volume / expected - 1.0,
            "bounds": mesh.bounds,
        },
        "ao": None
        if occlusion is None
        else {
            "mean": float(np.mean(occlusion)),
            "min": float(np.min(occlusion)),
            "max": float(np.max(occlusion)),
            "values": len(occlusion),
            "backend": job.backend,
        },
        "files": files,
        "split": job.split,
        "normalization": normalization(mesh),
        **extra,
    }


def resolved_backend(backend: str) -> str:
    """The backend that computes for a config's ``backend`` (``"auto"`` resolves to one).

    Parameters
    ----------
    backend : {"auto", "opencl", "numpy"}
        The configuration's backend.

    Returns
    -------
    {"opencl", "numpy"}
        ``"opencl"`` when an OpenCL device computes, else ``"numpy"``.

    Raises
    ------
    ao4d.opencl.cl.NoOpenCLDeviceError
        ``"opencl"`` and no OpenCL device works.
    """
    from ao4d.opencl import cl

    return cl.backend_name(cl.resolve_backend(backend, warn=False))


def _build_bvh(mesh: Any, backend: str) -> None:
    """Build (and cache on ``mesh``) the BVH that the AO rays and the renders will trace, on
    the device they run on, so that its time is a stage of its own."""
    from ao4d.bvh import get_bvh
    from ao4d.opencl import cl

    get_bvh(mesh, runtime=cl.resolve_backend(backend, warn=False))


def _render(
    render: dict,
    mesh: Any,
    occlusion: Any,
    settings: dict,
    seed: int,
    backend: str,
    title: str,
    timing: dict[str, float],
) -> bytes:
    """The PNG of the item seen along +w from its centre: a z-slice montage.

    Orthographic by default, framed tightly on the mesh's x, y, z extent (a perspective
    camera framing the whole 4D bounding sphere leaves most of the image empty).
    """
    import ao4d
    from ao4d.io.pictures import save_montage

    lo, hi = mesh.bounds
    if render.get("projection", "orthographic") == "orthographic":
        centre = (lo + hi) / 2
        eye = centre - [0, 0, 0, (hi[3] - lo[3]) + 1.0]
        camera = ao4d.Camera4D(
            eye,
            centre,
            up=(0, 1, 0, 0),
            over=(0, 0, 1, 0),
            projection="orthographic",
            half_width=1.05 * float(np.max(hi[:3] - lo[:3])) / 2,
        )
    else:
        camera = ao4d.Camera4D.framing(mesh.bounds, fov=float(render.get("fov", 40.0)), margin=1.0)
    vertex_ao = occlusion is not None and settings["ao"]["at"] == "vertices"
    with _stage(timing, f"render_{render['name']}"):
        result = ao4d.render(
            mesh,  # the item's own mesh: the render traces the BVH already built for it
            camera,
            tuple(render.get("shape", (32, 32, 32))),
            ao=occlusion if vertex_ao else "hits",
            samples=int(render.get("samples", 32)),
            seed=seed,
            backend=backend,
            progress=False,
        )
    # a fixed colour scale (shade = 1 - A in [0, 1]) makes items comparable, and a flat,
    # unoccluded view shows white rather than an arbitrary stretch of a constant image
    with _stage(timing, f"picture_{render['name']}"):
        return written_bytes(
            f"{render['name']}.png",
            lambda path: save_montage(
                path,
                result.shade,
                background=~result.hit,
                label="shade (1 - A)",
                title=title,
                vmin=0.0,
                vmax=1.0,
                spacing=result.geometry.spacing,
                origin=result.geometry.origin,
            ),
        )
