"""Make a dataset: every item of a configuration, reproducibly, resumably, in parallel.

Layout of an output folder::

    run.json                  configuration text, seed, ao4d version, lut checksum
    items/00000/mesh.npz      the closed 4D mesh (ao4d.mesh_files npz layout: SimplexMesh.load reads it)
    items/00000/ao.npz        occlusion per vertex (or per simplex), float64
    items/00000/<render>.png  optional renders (z-slice montage of the shaded 3D image)
    items/00000/samples.npz   optional learning samples (datasets_gen.samples)
    items/00000/sequence.npz  optional 3D frames along an axis (datasets_gen.sequence)
    items/00000/record.json   parameters, seeds, versions, mesh check, measures, file hashes
    items/00000/timing.json   wall-clock seconds per stage        (not hashed)
    items.csv                 one line per item
    manifest.json             sha256 and size of every file above except timing/summary
    summary.json              run statistics: made/skipped/failed, items per minute (not hashed)

Reproducibility: item ``i`` draws everything from ``np.random.SeedSequence([seed, i])`` (its
parameters, its rotation and its AO seed from three spawned children), so items can be made in
any order or process and give the same bytes. This holds for the same ao4d code (records carry
its version and the sha256 of its lookup tables and kernel sources) and the same AO device
(named in ``summary.json``: another device may round AO differently). Files carry no timestamps (npz members are dated
1980-01-01, JSON is canonical), and wall-clock data lives only in ``timing.json`` and
``summary.json``, which the manifest leaves out: two runs of the same configuration and seed
have byte-identical manifests.

Where: in this process (``workers=1``), in spawned processes (``workers=N``), or as tasks on a
dask.distributed scheduler (``scheduler="tcp://..."`` or ``"local:N"``): a worker that sees the
output (a shared folder, or an fsspec URL such as ``s3://bucket/run``: ``datasets_gen._store``)
writes its items there itself; any other makes its item in a scratch folder and returns the
files' bytes, which this process writes. The folder is the same byte for byte whichever way it
was made.

Resumability: ``record.json`` is written last, holding the sha256 of the item's other files; an
item counts as finished only when its record exists and every hash matches. Every file is
written atomically, so a killed run leaves finished items intact and at most stray temporary
files in the unfinished ones, which a rerun deletes before redoing them.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import math
import multiprocessing
import os
import signal
import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


from ._files import json_bytes, save_mesh_npz, sha256_file, write_json, write_npz
from ._store import LocalStore, Store, is_url, open_store
from .config import Config, ItemSpec, load_config, sample_params
from .splits import split_of

__all__ = ["run", "RunSummary", "item_seed", "item_complete", "RUN_FORMAT", "UNHASHED"]

RUN_FORMAT = 1
UNHASHED = ("timing.json", "summary.json", "manifest.json")


@dataclass
class RunSummary:
    """What a run did.

    Attributes
    ----------
    out : Path
    n_items, made, skipped : int
    failed : dict of int to str
        Item index -> error message.
    seconds : float
        Wall-clock time of the run.
    bytes : int
        Size of every hashed file in the folder.
    stages : dict of str to float
        Seconds per stage (``timing.json``'s names), summed over the items made.
    received : int
        Bytes of item files that came back to this process from dask workers (0 when the
        workers write their items themselves).
    made_items : set of int
        Indices of the items made (``made`` of them).
    """

    out: Path
    n_items: int
    made: int = 0
    skipped: int = 0
    failed: dict[int, str] = field(default_factory=dict)
    seconds: float = 0.0
    bytes: int = 0
    stages: dict[str, float] = field(default_factory=dict)
    received: int = 0
    made_items: set[int] = field(default_factory=set, repr=False)

    def add_timing(self, seconds: dict[str, float]) -> None:
        """Add one made item's stage seconds.

        Parameters
        ----------
        seconds : dict of str to float
            Seconds per stage of one item.
        """
        for name, value in seconds.items():
            self.stages[name] = self.stages.get(name, 0.0) + float(value)

    def stage_table(self) -> str:
        """Per-stage seconds summed over the items made, per item and as a share of the total.

        Returns
        -------
        str
            The table, one line per stage (renders and pictures grouped: ``render_*``,
            ``picture_*``).
        """
        grouped: dict[str, float] = {}
        for name, value in self.stages.items():
            key = name.split("_")[0] + "_*" if name.startswith(("render_", "picture_")) else name
            grouped[key] = grouped.get(key, 0.0) + value
        total = grouped.pop("total", sum(grouped.values()))
        if not self.made or total <= 0:
            return ""
        order = ["build", "check", "bvh", "ao", "render_*", "picture_*", "samples", "sequence", "write"]
        names = [n for n in order if n in grouped] + sorted(set(grouped) - set(order))
        other = total - sum(grouped.values())
        rows = [(n, grouped[n]) for n in names] + ([("other", other)] if other > 0.005 * total else [])
        lines = [f"  {'stage':<10} {'seconds':>9} {'per item':>9} {'share':>7}"]
        lines += [f"  {n:<10} {v:9.2f} {v / self.made:9.3f} {100 * v / total:6.1f}%" for n, v in rows]
        lines.append(f"  {'items':<10} {total:9.2f} {total / self.made:9.3f} {100.0:6.1f}%  "
                     f"(summed over {self.made} items; {self.items_per_minute:.1f} items/min wall)")
        return "\n".join(lines)

    @property
    def items_per_minute(self) -> float:
        """Items made per minute of wall-clock time (skipped items not counted)."""
        return 60.0 * self.made / self.seconds if self.seconds > 0 else math.nan

    def __str__(self) -> str:
        rate = f"{self.items_per_minute:.1f} items/min" if self.made else "nothing to make"
        lines = [f"{self.out}: {self.made} made, {self.skipped} skipped (already complete), "
                 f"{len(self.failed)} failed of {self.n_items}; {self.seconds:.1f} s, {rate}, "
                 f"{self.bytes / 2**20:.2f} MiB"]
        lines += [f"  item {i}: {msg}" for i, msg in sorted(self.failed.items())]
        table = self.stage_table()
        return "\n".join(lines + ([table] if table else []))


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


def item_dir(out: Path, index: int) -> Path:
    return Path(out) / "items" / f"{index:05d}"


def item_complete(folder: Path) -> bool:
    """True when ``folder/record.json`` exists and every file it lists has the recorded hash."""
    return _item_complete(LocalStore(Path(folder)), "")


def _item_rel(index: int) -> str:
    """An item's folder relative to the run's root (``item_dir``'s, as a store path)."""
    return f"items/{index:05d}"


def _item_complete(store: Store, rel: str) -> bool:
    def at(name: str) -> str:
        return f"{rel}/{name}" if rel else name

    try:
        record = json.loads(store.read_text(at("record.json")))
        files = record["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return False
    for name, digest in files.items():
        if not store.is_file(at(name)) or store.sha256(at(name)) != digest:
            return False
    return True


def _versions() -> dict[str, str]:
    """ao4d version and the lookup tables' checksum (sha256 of lut/manifest.json)."""
    import ao4d
    from ao4d._resources import data_dir

    manifest = data_dir("lut") / "manifest.json"
    tables = json.loads(manifest.read_text(encoding="utf-8")).get("files", {})
    kernels = hashlib.sha256()
    for path in sorted(data_dir("kernels").iterdir()):
        if path.suffix in (".cl", ".h"):
            kernels.update(path.name.encode() + b"\0" + path.read_bytes())
    return {
        "ao4d": ao4d.__version__,
        "kernels_sha256": kernels.hexdigest(),
        "lut_manifest_sha256": sha256_file(manifest),
        "lut_cube_4d_sha256": tables.get("cube_4d.npz", {}).get("sha256", ""),
        "lut_simplex_4d_sha256": tables.get("simplex_4d.npz", {}).get("sha256", ""),
    }


# --------------------------------------------------------------------------- one item


@dataclass(frozen=True)
class _Job:
    spec: ItemSpec
    seed: int
    out: str
    backend: str
    run_sha256: str = ""  # of out/run.json: a worker that reads the same sees the same folder
    split: str | None = None  # the item's split (datasets_gen.splits), None without a split table


@contextlib.contextmanager
def _stage(timing: dict[str, float], name: str):
    """Add the wall-clock seconds of the ``with`` block to ``timing[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timing[name] = timing.get(name, 0.0) + time.perf_counter() - t0


def make_item(job: _Job) -> dict[str, Any]:
    """Make item ``job.spec.index`` in its folder; returns its timing. Top-level: spawn-safe.

    ``timing.json`` holds the wall-clock seconds of each stage: ``build`` (field, grid and
    extraction, or the lifted solid), ``check`` (mesh check, volume, measure), ``bvh`` (the
    tree the AO rays and the renders trace), ``ao``, ``render_<name>`` (primary rays, AO at
    hits, shading) and ``picture_<name>`` (the PNG) per render, ``samples`` and ``sequence``
    (the labelled points and the frames, when the config asks), ``write`` (every file and
    hash), and ``total``.
    """
    from .families import build_shape, random_rotation
    from .samples import normalization

    start = time.perf_counter()
    spec, folder = job.spec, item_dir(Path(job.out), job.spec.index)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.iterdir():  # leftovers of an interrupted attempt (no valid record)
        if stale.is_file():
            stale.unlink()
    settings = spec.family.settings
    # spawn(5)'s first three children are spawn(3)'s: samples left the meshes, AO and renders as they were
    params_ss, rotation_ss, ao_ss, samples_ss, sequence_ss = item_seed(job.seed, spec.index).spawn(5)
    rng = np.random.default_rng(params_ss)
    params = sample_params(spec.family.params, rng)
    rotation = (random_rotation(np.random.default_rng(rotation_ss))
                if settings["rotation"] == "random" else None)
    ao_seed = int(ao_ss.generate_state(1)[0])
    timing: dict[str, float] = {}

    with _stage(timing, "build"):
        shape = build_shape(spec.family.kind, params, settings, rng, rotation)
    mesh = shape.mesh
    with _stage(timing, "check"):
        report = mesh.check()
        volume, measure = float(mesh.volume), float(mesh.measure)
    with _stage(timing, "write"):
        files = [save_mesh_npz(folder / "mesh.npz", mesh).name]

    occlusion = None
    if settings["ao"] or settings["renders"]:
        with _stage(timing, "bvh"):
            _build_bvh(mesh, job.backend)
    if settings["ao"]:
        import ao4d

        ao = settings["ao"]
        with _stage(timing, "ao"):
            occlusion = ao4d.ambient_occlusion(mesh, samples=ao["samples"], max_distance=ao["max_distance"],
                                               at=ao["at"], seed=ao_seed, backend=job.backend,
                                               progress=False)
        with _stage(timing, "write"):
            files.append(write_npz(folder / "ao.npz", {"occlusion": np.asarray(occlusion, np.float64)}).name)

    extra: dict[str, Any] = {}
    if settings.get("samples"):
        from .samples import make_samples

        with _stage(timing, "samples"):
            arrays, extra["samples"] = make_samples(
                shape, spec.family.kind, settings["samples"], np.random.default_rng(samples_ss),
                occlusion=occlusion, ao_at=settings["ao"]["at"] if settings["ao"] else "vertices",
                backend=job.backend)
        with _stage(timing, "write"):
            files.append(write_npz(folder / "samples.npz", arrays).name)
    if settings.get("sequence"):
        from .sequence import make_sequence

        with _stage(timing, "sequence"):
            arrays, extra["sequence"] = make_sequence(
                shape, spec.family.kind, settings["sequence"], occlusion=occlusion,
                ao_at=settings["ao"]["at"] if settings["ao"] else "vertices",
                samples=settings.get("samples") or None, rng=np.random.default_rng(sequence_ss),
                backend=job.backend)
        with _stage(timing, "write"):
            files.append(write_npz(folder / "sequence.npz", arrays).name)

    for render in settings["renders"]:
        title = f"item {spec.index}: {spec.family.name} ({spec.family.kind}), looking along +w"
        files.append(_render(folder, render, mesh, occlusion, settings, ao_seed, job.backend,
                             title, timing).name)

    with _stage(timing, "write"):
        expected = shape.volume_expected
        record = {
            "format": RUN_FORMAT,
            "index": spec.index,
            "family": spec.family.name,
            "kind": spec.family.kind,
            "number": spec.number,
            "seed": {"run": job.seed, "entropy": [job.seed, spec.index], "ao": ao_seed},
            "params": params,
            "derived": shape.derived,
            "rotation": rotation,
            "settings": {k: v for k, v in settings.items() if k != "renders"},
            "renders": settings["renders"],
            "grid": shape.grid,
            "versions": _versions(),
            "mesh": {
                "vertices": mesh.n_vertices,
                "simplices": mesh.n_simplices,
                "check": {**asdict(report), "ok": report.ok},
                "volume": volume,
                "measure": measure,
                "volume_expected": expected,
                "volume_rel_error": None if not expected else volume / expected - 1.0,
                "bounds": mesh.bounds,
            },
            "ao": None if occlusion is None else {
                "mean": float(np.mean(occlusion)), "min": float(np.min(occlusion)),
                "max": float(np.max(occlusion)), "values": len(occlusion),
                "backend": _backend_ran(job.backend)},
            "files": {name: sha256_file(folder / name) for name in files},
            "split": job.split,
            "normalization": normalization(mesh),
            **extra,
        }
    timing["total"] = time.perf_counter() - start
    write_json(folder / "timing.json", {"seconds": timing, "pid": os.getpid()})
    write_json(folder / "record.json", record)  # last: marks the item complete
    return {"index": spec.index, "seconds": timing}


def _build_bvh(mesh: Any, backend: str) -> None:
    """Build (and cache on ``mesh``) the BVH that the AO rays and the renders will trace, on
    the device they run on, so that its time is a stage of its own."""
    from ao4d import cl
    from ao4d.raycast import get_bvh

    get_bvh(mesh, runtime=cl.resolve_backend(backend, warn=False))


def _render(folder: Path, render: dict, mesh: Any, occlusion: Any, settings: dict, seed: int,
            backend: str, title: str, timing: dict[str, float]) -> Path:
    """Render the item looking along +w at its centre; save a z-slice montage PNG.

    Orthographic by default, framed tightly on the mesh's x, y, z extent (a perspective
    camera framing the whole 4D bounding sphere leaves most of the image empty).
    """
    import ao4d
    from ao4d.pictures import save_montage

    lo, hi = mesh.bounds
    if render.get("projection", "orthographic") == "orthographic":
        centre = (lo + hi) / 2
        eye = centre - [0, 0, 0, (hi[3] - lo[3]) + 1.0]
        camera = ao4d.Camera4D(eye, centre, up=(0, 1, 0, 0), over=(0, 0, 1, 0),
                               projection="orthographic",
                               half_width=1.05 * float(np.max(hi[:3] - lo[:3])) / 2)
    else:
        camera = ao4d.Camera4D.framing(mesh.bounds, fov=float(render.get("fov", 40.0)), margin=1.0)
    vertex_ao = occlusion is not None and settings["ao"]["at"] == "vertices"
    # the item's own mesh (not a copy), so the render traces the BVH already built for it; the
    # mesh file is written, and the occlusion is attached only for the render
    if vertex_ao:
        mesh.point_data["ao"] = occlusion
    try:
        with _stage(timing, f"render_{render['name']}"):
            result = ao4d.render(mesh, camera, tuple(render.get("shape", (32, 32, 32))),
                                 ao="vertices" if vertex_ao else "hits",
                                 samples=int(render.get("samples", 32)), seed=seed, backend=backend,
                                 progress=False)
    finally:
        if vertex_ao:
            del mesh.point_data["ao"]
    path = folder / f"{render['name']}.png"
    # a fixed colour scale (shade = 1 - A in [0, 1]) makes items comparable, and a flat,
    # unoccluded view shows white rather than an arbitrary stretch of a constant image
    with _stage(timing, f"picture_{render['name']}"):
        save_montage(path, result.shade, background=~result.hit, label="shade (1 - A)",
                     title=title, vmin=0.0, vmax=1.0,
                     spacing=result.geometry.spacing, origin=result.geometry.origin)
    return path


# --------------------------------------------------------------------------- the run


def _read_run_info(store: Store) -> dict[str, Any]:
    """``run.json`` of the store, checked: a damaged one is an error naming the file."""
    where = f"{store.name.rstrip('/')}/run.json"
    try:
        info = json.loads(store.read_text("run.json"))
    except (OSError, ValueError) as exc:  # unreadable, not UTF-8, not JSON
        raise ValueError(f"`out` {store.name!r}: its run.json ({where}) is unreadable or damaged "
                         f"({type(exc).__name__}: {exc}); it names the run the folder holds, so "
                         "nothing can be resumed there: restore it, or choose another folder") from None
    if not isinstance(info, dict) or not isinstance(info.get("config_sha256"), str) \
            or isinstance(info.get("seed"), bool) or not isinstance(info.get("seed"), int):
        raise ValueError(f"`out` {store.name!r}: its run.json ({where}) is damaged (no "
                         "config_sha256 and seed of a datasets_gen run); restore it, or choose "
                         "another folder")
    return info


def _run_info(config: Config, seed: int) -> bytes:
    return json_bytes({
        "format": RUN_FORMAT, "config_name": config.name, "config_source": config.source,
        "config_sha256": config.sha256, "config_text": config.text, "seed": seed,
        "versions": _versions(), "n_items": len(config.items()),
    })


def _check_same_run(store: Store, config: Config, seed: int) -> None:
    """Refuse when the store's ``run.json`` is of another config or seed (or damaged)."""
    previous = _read_run_info(store)
    if previous["config_sha256"] == config.sha256 and previous["seed"] == seed:
        return
    theirs = f"config {previous.get('config_name')!r} with seed {previous['seed']} " \
             f"({previous.get('config_source')}, text sha256 {previous['config_sha256'][:12]})"
    ours = f"config {config.name!r} with seed {seed} ({config.source}, text sha256 {config.sha256[:12]})"
    why = ("the seeds differ" if previous["config_sha256"] == config.sha256 else
           "the configs' texts differ" if previous.get("config_name") == config.name else
           "another config")
    raise FileExistsError(
        f"`out` {store.name!r} holds a run of {theirs}, not of {ours} ({why}); one folder holds "
        "one run (that run may still be going): choose another folder, or delete it")


def _check_out(store: Store | str | os.PathLike, config: Config, seed: int) -> None:
    """Create ``run.json`` in the store (or folder) or refuse an output folder made by another
    config or seed. The creation is exclusive on a local folder, so of two runs started into
    one new folder at once, one is refused."""
    store = store if isinstance(store, Store) else open_store(store)
    out = store.name
    holds_something = store.prepare()
    if store.is_file("run.json"):
        _check_same_run(store, config, seed)
        return
    if holds_something:
        raise FileExistsError(f"`out` {out!r} exists, is not empty and holds no run.json; "
                              "choose an empty or new folder")
    try:
        created = store.create_bytes("run.json", _run_info(config, seed))
    except OSError as exc:  # a read-only file system, a full disk, no permission
        raise ValueError(f"cannot write into the output folder `out` {out!r}: "
                         f"{exc.strerror or exc}") from None
    if not created:  # another run created it since prepare() looked
        _check_same_run(store, config, seed)


def run(
    config: str | os.PathLike | Config,
    out: str | os.PathLike,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    seed: int | None = None,
    progress: bool | None = None,
) -> RunSummary:
    """Make (or finish) the dataset of ``config`` in the folder ``out``.

    Parameters
    ----------
    config : str, path or Config
        A configuration file, a shipped configuration's name (``"smoke"``, ``"tori"``, ...) or
        a loaded :class:`~datasets_gen.config.Config`.
    out : path-like or str
        Output folder: new, empty, or holding an earlier (partial) run of the same config/seed.
        A local path, or an fsspec URL (``s3://bucket/run``, ``gs://...``, ``file:///...``;
        the protocol's package, such as ``s3fs``, must be installed): then every process
        that makes items writes its own into the URL, with the same atomic protocol, and
        this process writes only ``run.json``, the index and the manifest.
    workers : int
        Processes (spawned); 1 runs in this process.
    scheduler : str, optional
        Run the items as tasks on a dask.distributed scheduler instead: its address
        (``"tcp://host:8786"``) or ``"local:N"`` for a LocalCluster of N worker processes (one
        thread each) started and stopped here. A worker that sees the output folder (its
        ``run.json`` has this run's hash: a shared filesystem, a LocalCluster, or a URL
        ``out``) writes its items there itself; any other makes its item in a scratch folder
        and sends the files back for this process to write (atomically, the record last), so
        workers need ao4d but no shared filesystem. The files, and so the manifest,
        are byte-identical to a ``workers=1`` run on the same software and AO device; a worker
        lost mid-item has its item redone on another worker (dask's own rescheduling).
    seed : int, optional
        Run seed; default the configuration's ``seed``.
    progress : bool, optional
        tqdm bar over items; default when stderr is a terminal.

    Returns
    -------
    RunSummary
        What was made and skipped, and the time per stage.

    Raises
    ------
    FileExistsError
        ``out`` holds something else (another config or seed, or unrelated files), or another
        run wrote its own ``run.json`` there while this one ran.
    ValueError
        Before any work: a malformed URL, a damaged ``run.json``, ``workers > 1`` into a
        filesystem that lives in this process (``memory://``), an ``AO4D_DEVICE`` that names
        no working device (:class:`ao4d.cl.DeviceSelectionError`). After the items: the index
        cannot be written (a full disk; the message names the file, the items are kept).
    """
    from ao4d._validate import check_positive_int

    cfg = config if isinstance(config, Config) else load_config(config)
    workers = check_positive_int(workers, "workers")
    store = open_store(out)  # an unknown URL protocol fails here, before any work
    if store.process_local and workers > 1:
        raise ValueError(f"`out` {store.name!r} lives in this process only, so the {workers} "
                         "`workers` processes could not write their items into it: use "
                         "workers=1, a folder, or a URL every process reaches (file://, s3://)")
    if scheduler is not None:
        _check_scheduler(scheduler)
        if workers != 1:
            raise ValueError(f"give `workers` ({workers}) or `scheduler` ({scheduler!r}), not both")
        _probe_scheduler(scheduler)  # before the output folder is touched
    seed = cfg.seed if seed is None else check_positive_int(seed, "seed", minimum=0)
    _device_name()  # an impossible AO4D_DEVICE fails here, before the folder is touched
    _check_out(store, cfg, seed)
    run_sha256 = store.sha256("run.json")
    items = cfg.items()
    summary = RunSummary(out if is_url(out) else Path(out), len(items))
    start = time.perf_counter()
    todo = []
    for spec in items:
        if _item_complete(store, _item_rel(spec.index)):
            summary.skipped += 1
        else:
            todo.append(_Job(spec, seed, str(out), cfg.backend, run_sha256,
                             split_of(cfg.split, seed, spec.index)))

    from ao4d import _progress

    # on a terminal a bar; in a log a line every few seconds (items take seconds to minutes)
    bar = _progress.bar(len(items), f"{cfg.name} items", unit="item", initial=summary.skipped,
                        show=True if progress is None else bool(progress))
    try:
        if scheduler is not None and todo:
            _run_distributed(todo, scheduler, store, summary, bar)
        elif workers == 1 or len(todo) <= 1:
            for job in todo:
                _collect(summary, job, lambda job=job: make_item_anywhere(job))
                bar.update()
        else:
            _run_parallel(todo, workers, summary, bar)
    except KeyboardInterrupt:
        bar.close()
        print(f"\ninterrupted: finished items are kept; rerun the same command to resume "
              f"({summary.made + summary.skipped} of {len(items)} complete)", file=sys.stderr)
        raise
    bar.close()
    summary.seconds = time.perf_counter() - start
    try:
        ours = store.sha256("run.json") == run_sha256
    except OSError:
        ours = False
    if not ours:  # another run wrote its own run.json meanwhile, or it was removed
        _check_same_run(store, cfg, seed)
    try:
        summary.bytes = _write_index(store, items, summary)
    except OSError as exc:  # a full disk, a lost mount: the items already written are kept
        raise ValueError(f"cannot write the index of `out` {store.name!r} "
                         f"({getattr(exc, 'filename', None) or 'items.csv, manifest.json'}): "
                         f"{exc.strerror or exc}; the finished items are kept: make room and "
                         "rerun the same command to finish") from None
    return summary


def _collect(summary: RunSummary, job: _Job, call) -> None:
    try:
        result = call()
        summary.made += 1
        summary.made_items.add(job.spec.index)
        summary.add_timing((result or {}).get("seconds", {}))
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # one bad item must not stop the dataset; reported at the end
        summary.failed[job.spec.index] = f"{type(exc).__name__}: {exc}"


def _run_parallel(todo: list[_Job], workers: int, summary: RunSummary, bar) -> None:
    context = multiprocessing.get_context("spawn")  # no fork: OpenCL state must not be copied
    with ProcessPoolExecutor(max_workers=min(workers, len(todo)), mp_context=context,
                             initializer=_ignore_sigint) as pool:
        pending: dict[Future, _Job] = {pool.submit(make_item_anywhere, job): job for job in todo}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    job = pending.pop(fut)
                    _collect(summary, job, fut.result)
                    bar.update()
        except KeyboardInterrupt:
            workers_ = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in workers_:
                proc.terminate()  # their unfinished items are redone on the next run
            raise


def _check_scheduler(scheduler: Any) -> int | None:
    """The worker count of ``"local:N"``, None for an address; errors name the parameter."""
    if not isinstance(scheduler, str) or not scheduler.strip():
        raise TypeError(f"`scheduler` must be an address or 'local:N', got {scheduler!r}")
    if scheduler.startswith("local:"):
        count = scheduler[len("local:"):]
        if not count.isdigit() or int(count) < 1:
            raise ValueError(f"`scheduler` 'local:N' needs a worker count N >= 1, got {scheduler!r}")
        return int(count)
    return None


# How long a scheduler address may take to accept a connection and greet it: a dask scheduler
# sends its handshake at once, so silence means something else listens there
SCHEDULER_PROBE_SECONDS = 10.0
# A dask handshake is well under this; a first word beyond it is not dask's protocol (an HTTP
# reply read as a frame length asks for exbibytes)
_HANDSHAKE_MAX_BYTES = 1 << 20


def _probe_scheduler(scheduler: str) -> None:
    """Fail fast, with a clear message, when a ``tcp://`` address is not a dask scheduler.

    dask's own connect timeout covers only the TCP connection: a listener that accepts and
    never answers stalls the client for minutes, and an HTTP server's reply is read as a frame
    length (``Unable to allocate 3.07 EiB``). A dask scheduler writes its handshake, an 8-byte
    length and a small message, as soon as it accepts; this reads those 8 bytes and closes.
    Other protocols (``tls://``, ``ucx://``, ``inproc://``) are left to dask.
    """
    import socket
    from urllib.parse import urlsplit

    if scheduler.startswith("local:"):
        return
    parts = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
    if parts.scheme != "tcp":
        return
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host = port = None
    if not host or port is None:
        raise ValueError(f"`scheduler` {scheduler!r} is not an address of the form "
                         "tcp://HOST:PORT (or 'local:N')")
    where = f"the dask scheduler at `scheduler` {scheduler!r}"
    wait = SCHEDULER_PROBE_SECONDS
    try:
        sock = socket.create_connection((host, port), timeout=wait)
    except OSError as exc:
        raise ValueError(f"cannot reach {where}: {exc}") from None
    head = b""
    with sock:
        try:
            while len(head) < 8:
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    break
                head += chunk
        except TimeoutError:
            pass
        except OSError as exc:
            raise ValueError(f"cannot reach {where}: {exc}") from None
    if not head:
        raise ValueError(f"cannot reach {where}: it accepted the connection but sent nothing in "
                         f"{wait:g} s (a dask scheduler greets every connection at once); is it a "
                         "dask scheduler's address (usually port 8786)?")
    if head[:5].upper() in (b"HTTP/", b"<HTML", b"<!DOC") or not (
            len(head) == 8 and 0 < int.from_bytes(head, "little") <= _HANDSHAKE_MAX_BYTES):
        kind = "an HTTP server" if head[:5].upper() == b"HTTP/" else "something else"
        raise ValueError(f"cannot use {where}: it answers like {kind}, not a dask scheduler "
                         f"(first bytes {head!r}); is it the dashboard's port (8787) instead of "
                         "the scheduler's (8786)?")


def make_item_files(job: _Job) -> dict[str, Any]:
    """Make an item in a scratch folder and return its files' bytes (runs on a dask worker).

    The item is made by :func:`make_item` exactly as locally, only in a temporary folder of
    the worker; the client writes the returned files with :func:`write_item_files`.
    """
    import dataclasses
    import tempfile

    with tempfile.TemporaryDirectory(prefix="datasets_gen-item-") as scratch:
        timing = make_item(dataclasses.replace(job, out=scratch))
        folder = item_dir(Path(scratch), job.spec.index)
        files = {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}
    if "record.json" not in files:
        raise RuntimeError(f"item {job.spec.index} left no record.json")
    return {"index": job.spec.index, "files": files, "timing": timing}


# Workers write their items into the output folder themselves whenever they see it (set to
# False to have every item's bytes sent back to the client, as for workers without the folder)
_WORKERS_WRITE = True


def make_item_anywhere(job: _Job) -> dict[str, Any]:
    """Make an item into its run's output: :func:`make_item` in a local folder; for a URL,
    in a scratch folder whose files this process then writes into the URL itself
    (:func:`write_item_files`). Returns its timing. Top-level: spawn-safe."""
    if not is_url(job.out):
        return make_item(job)
    made = make_item_files(job)
    write_item_files(open_store(job.out), job.spec.index, made["files"])
    return made["timing"]


def make_item_on_worker(job: _Job) -> dict[str, Any]:
    """Make an item on a dask worker, in the output folder itself when the worker sees it.

    The worker sees the folder when its ``run.json`` has the client's hash (a shared
    filesystem, a LocalCluster on the client's machine, or a URL it can reach): it makes the
    item there as in one process (each file atomic, ``record.json`` last) and returns only
    its timing. Otherwise it makes the item in a scratch folder and returns the files' bytes
    (:func:`make_item_files`) for the client to write.
    """
    try:
        sees = bool(job.run_sha256) and open_store(job.out).sha256("run.json") == job.run_sha256
    except (OSError, ValueError):
        sees = False
    if not sees:
        return make_item_files(job)
    return {**make_item_anywhere(job), "written": True}


def write_item_files(store: Store, index: int, files: dict[str, bytes]) -> None:
    """Write an item's files into its folder, each atomically, ``record.json`` last (it marks
    the item complete), after deleting leftovers of an interrupted attempt."""
    rel = _item_rel(index)
    for stale in store.files(rel):
        if stale not in files:
            store.remove(f"{rel}/{stale}")
    store.remove(f"{rel}/record.json")
    for name in sorted(files, key=lambda n: n == "record.json"):
        store.write_bytes(f"{rel}/{name}", files[name])


def _run_distributed(todo: list[_Job], scheduler: str, store: Store, summary: RunSummary, bar) -> None:
    """Items as tasks on a dask.distributed scheduler; workers that see the folder write their
    items themselves, the others send them back to be written here as they arrive."""
    import dataclasses
    import uuid

    from distributed import Client, LocalCluster, as_completed

    count = _check_scheduler(scheduler)
    cluster = None
    try:
        if count is not None:
            from ao4d.blockwise import worker_environment

            # glibc's default malloc in the workers: dask's MALLOC_TRIM_THRESHOLD_ slows numpy
            with worker_environment():
                cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True,
                                       dashboard_address=":0")
            client = Client(cluster)
        else:
            client = Client(scheduler)  # waits distributed.comm.timeouts.connect (30 s)
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise ValueError(f"cannot reach the dask scheduler at `scheduler` {scheduler!r}: {exc}") from None
    run_id = uuid.uuid4().hex[:8]
    futures: dict[Any, _Job] = {}
    try:
        for job in todo:
            key = f"datasets_gen-item-{job.spec.index:05d}-{run_id}"
            where = job.out if is_url(job.out) else str(Path(job.out).resolve())
            task = dataclasses.replace(job, out=where,
                                       run_sha256=job.run_sha256 if _WORKERS_WRITE else "")
            futures[client.submit(make_item_on_worker, task, key=key, pure=False)] = job
        for future in as_completed(list(futures)):
            job = futures[future]

            def write(future=future, job=job) -> dict:
                result = future.result()
                if result.get("written"):  # the worker wrote the item into the folder
                    return result
                write_item_files(store, job.spec.index, result["files"])
                summary.received += sum(len(b) for b in result["files"].values())
                return result["timing"]

            _collect(summary, job, write)
            future.release()
            bar.update()
    except KeyboardInterrupt:
        client.cancel(list(futures))  # unfinished items are redone on the next run
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _ignore_sigint() -> None:
    """Workers leave Ctrl-C to the parent, which cancels and terminates them."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _write_index(store: Store, items: list[ItemSpec], summary: RunSummary) -> int:
    """Write items.csv, manifest.json (hashes) and summary.json; return the hashed bytes."""
    records: dict[int, dict] = {}  # each complete item's record (never a failed or interrupted one)
    for spec in items:
        rel = _item_rel(spec.index)
        if spec.index in summary.failed:
            continue
        if not store.is_file(f"{rel}/record.json"):
            if spec.index in summary.made_items:  # never count an item the store does not hold
                summary.made -= 1
                summary.failed[spec.index] = f"made, but its record.json is not in `out` {store.name!r}"
            continue
        records[spec.index] = json.loads(store.read_text(f"{rel}/record.json"))
    rows = []
    for index, rec in records.items():
        m = rec["mesh"]
        rows.append([index, rec["family"], rec["kind"], m["vertices"], m["simplices"],
                     m["check"]["ok"], repr(m["volume"]), repr(m["volume_expected"]),
                     repr(m["volume_rel_error"]), repr(rec["ao"]["mean"]) if rec["ao"] else "",
                     rec.get("split") or ""])
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(["index", "family", "kind", "vertices", "simplices", "ok", "volume",
                     "volume_expected", "volume_rel_error", "ao_mean", "split"])
    writer.writerows(rows)
    store.write_bytes("items.csv", text.getvalue().encode("utf-8"))

    # top-level files, and each complete item's record and the files it lists (never the
    # leftovers of a failed or interrupted item). Item files carry the hashes their record
    # holds (made when they were written, checked when a rerun found the item complete), so
    # no item's bytes are read here again: only the records'.
    known: dict[str, str | None] = {name: None for name in store.files()}
    for index, rec in records.items():
        rel = _item_rel(index)
        known[f"{rel}/record.json"] = None
        for name, digest in rec["files"].items():
            known[f"{rel}/{name}"] = digest
    files = {}
    for rel in sorted(known):
        name = rel.rpartition("/")[2]
        if name not in UNHASHED and not name.startswith("."):
            files[rel] = {"sha256": known[rel] or store.sha256(rel), "bytes": store.size(rel)}
    run_info = json.loads(store.read_text("run.json"))
    store.write_bytes("manifest.json", json_bytes({
        "format": RUN_FORMAT,
        "config_sha256": run_info["config_sha256"],
        "seed": run_info["seed"],
        "n_items": len(items),
        "complete": len(rows) == len(items),
        "unhashed": list(UNHASHED),
        "files": files,
    }))
    size = sum(f["bytes"] for f in files.values())
    store.write_bytes("summary.json", json_bytes({
        "device": _device_name(),
        "made": summary.made, "skipped": summary.skipped, "failed": summary.failed,
        "seconds": summary.seconds, "items_per_minute": summary.items_per_minute,
        "bytes": size, "stages": summary.stages,
    }))
    return size


def _device_name() -> str:
    """The OpenCL device ao4d would use here (AO values may differ in the last bits between
    devices, so a dataset is byte-reproducible on the same software and device)."""
    from ao4d import cl

    return cl.describe(cl.resolve_backend("auto", warn=False))


def _backend_ran(backend: str) -> str:
    """The backend that computes for a requested ``backend`` ("auto" resolves to one)."""
    from ao4d import cl

    return cl.backend_name(cl.resolve_backend(backend, warn=False))


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m datasets_gen CONFIG --out DIR [--workers N | --scheduler
    ADDRESS|local:N] [--seed S]``."""
    import argparse

    from .config import ConfigError, describe, shipped_configs

    parser = argparse.ArgumentParser(
        prog="python -m datasets_gen",
        description="Make a reproducible procedural 4D dataset (meshes, AO, renders, manifest).",
        epilog="shipped configs: " + ", ".join(shipped_configs()) + "\nexamples:\n"
               "  python -m datasets_gen smoke --out /tmp/smoke\n"
               "  python -m datasets_gen tori --out data/tori --workers 2 --seed 7\n"
               "  python -m datasets_gen tori --out data/tori --scheduler local:4\n"
               "  python -m datasets_gen tori --out data/tori --scheduler tcp://head:8786\n"
               "  python -m datasets_gen tori --out s3://bucket/tori --scheduler tcp://head:8786\n"
               "  python -m datasets_gen my.toml --out data/mine   # rerun to resume\n"
               "  python -m datasets_gen export data/mine --format webdataset --out shards/",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("config", nargs="?", help="a TOML file or the name of a shipped config")
    parser.add_argument("--out", help="output folder (created; reruns resume), or an fsspec URL "
                                      "(s3://bucket/run, file:///shared/run) that the workers "
                                      "write their items into; required unless --list")
    parser.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    parser.add_argument("--scheduler", metavar="ADDRESS|local:N",
                        help="run the items on a dask.distributed scheduler (an address such as "
                             "tcp://head:8786, or local:N for a LocalCluster of N processes)")
    parser.add_argument("--seed", type=int, default=None, help="run seed (default: the config's)")
    parser.add_argument("--list", action="store_true", help="show the items' families and exit")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--kinds", action="store_true",
                        help="list the family kinds and their parameters, and exit")
    args = parser.parse_args(argv)
    if args.kinds:
        from .families import kinds

        for name, kind in kinds().items():
            print(f"{name}({', '.join(kind.params)})\n    {kind.doc.splitlines()[0].strip()}")
        return 0
    if args.config is None:
        parser.error("the following arguments are required: config")
    if args.out is None and not args.list:
        parser.error("the following arguments are required: --out")
    try:
        cfg = load_config(args.config)
        if args.list:
            print(f"{cfg.name} ({cfg.source}): {len(cfg.items())} items\n{describe(cfg)}")
            return 0
        if open_store(args.out).process_local:
            raise ValueError(f"`--out` {args.out!r} is a filesystem inside this process: "
                             "everything written there is gone when the command exits; give a "
                             "folder or a URL that outlives it (file://, s3://, ...)")
        if args.no_progress:
            from ao4d import _progress

            _progress.set_enabled(False)
        summary = run(cfg, args.out, workers=args.workers, scheduler=args.scheduler, seed=args.seed,
                      progress=False if args.no_progress else None)
    except (FileNotFoundError, FileExistsError, ConfigError, ValueError, TypeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    print(summary)
    return 1 if summary.failed else 0
