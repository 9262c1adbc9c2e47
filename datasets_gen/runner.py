"""Make a dataset: every item of a configuration, reproducibly, resumably, in parallel.

Layout of an output folder::

    run.json                  configuration text, seed, ao4d version, lut checksum
    items/00000/mesh.npz      the closed 4D mesh (ao4d.io.mesh_files npz layout: SimplexMesh.load reads it)
    items/00000/ao.npz        occlusion per vertex (or per simplex), float64
    items/00000/<render>.png  optional renders (z-slice montage of the shaded 3D image)
    items/00000/samples.npz   optional learning samples (datasets_gen.samples)
    items/00000/sequence.npz  optional 3D frames along an axis (datasets_gen.sequence)
    items/00000/record.json   parameters, seeds, versions, mesh check, measures, file hashes
    items/00000/timing.json   wall-clock seconds per stage        (not hashed)
    items.csv                 one line per item
    manifest.json             sha256 and size of every file above except timing/summary
    summary.json              run statistics: made/skipped/failed, items per minute (not hashed)

Three ideas, three modules: making one item (:mod:`datasets_gen.items`), where the items are
made (:mod:`datasets_gen.executors`: this process, spawned processes, dask.distributed) and
the run's index (:mod:`datasets_gen.index`: ``run.json``, ``items.csv``, the manifest). This
module joins them: :func:`run` and the command line.

Reproducibility: item ``i`` draws everything from ``np.random.SeedSequence([seed, i])``, so
items can be made in any order or process and give the same bytes. This holds for the same
ao4d code (records carry its version and the sha256 of its lookup tables and kernel sources)
and the same AO device (named in ``summary.json``: another device may round AO differently).
Files carry no timestamps (npz members are dated 1980-01-01, JSON is canonical), and
wall-clock data lives only in ``timing.json`` and ``summary.json``, which the manifest leaves
out: two runs of the same configuration and seed have byte-identical manifests.

Resumability: every file is written atomically through the run's store
(:mod:`datasets_gen._store`: a folder or an fsspec URL), an item's ``record.json`` last; an
item counts as finished only when its record exists and every hash matches, so a killed run
leaves finished items intact, and a rerun redoes the others.
"""

from __future__ import annotations

import os
import sys
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ._store import Store, is_url, open_store
from .config import Config, load_config
from .executors import Executor, executor_for
from .index import RunSummary, check_same_run, claim_out, device_name, write_index
from .items import Job, foreign_files, item_complete, item_seed, resolved_backend
from .splits import empty_splits, split_counts, split_of

__all__ = ["run", "RunSummary", "item_seed", "main"]


def run(
    config: str | os.PathLike | Mapping[str, Any] | Config,
    out: str | os.PathLike,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    executor: Executor | None = None,
    seed: int | None = None,
    progress: bool | None = None,
) -> RunSummary:
    """Make (or finish) the dataset of ``config`` in the folder ``out``.

    Parameters
    ----------
    config : str, path, mapping or Config
        A configuration file, a shipped configuration's name (``"smoke"``, ``"tori"``, ...), a
        mapping (:func:`~datasets_gen.load_config`) or a loaded
        :class:`~datasets_gen.config.Config`.
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
        ``out``) writes its items there itself; any other makes its item in memory and sends
        the files back for this process to write (atomically, the record last), so workers
        need ao4d but no shared filesystem. The files, and so the manifest, are
        byte-identical to a ``workers=1`` run on the same software and AO device; a worker
        lost mid-item has its item redone on another worker (dask's own rescheduling).
    executor : Executor, optional
        Where the items are made, given in full instead of ``workers`` and ``scheduler``
        (:mod:`datasets_gen.executors`: ``InProcess()``, ``ProcessPool(n)``,
        ``Dask(address, workers_write=False)``, ...).
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
        no working device (:class:`ao4d.opencl.cl.DeviceSelectionError`). After the items: the index
        cannot be written (a full disk; the message names the file, the items are kept).
    ao4d.opencl.cl.NoOpenCLDeviceError
        Before any work: the config's ``backend`` is ``"opencl"`` and no OpenCL device works.

    Warns
    -----
    UserWarning
        A split named in the config's ``split`` table gets no item (a fraction of 0, or too
        few items): it exists, empty; ``summary.json`` lists it under ``empty_splits``. An
        item to be remade holds files no run writes (they are left as they are).
    """
    cfg = config if isinstance(config, Config) else load_config(config)
    executor = _executor(workers, scheduler, executor)
    store = _open_out(out, executor, lasting=False)
    return _make(cfg, store, out, executor, seed, progress)


def _executor(workers: Any, scheduler: str | None, executor: Executor | None) -> Executor:
    """The executor of ``workers`` and ``scheduler``, or ``executor`` given in full."""
    from ao4d._validate import check_positive_int

    workers = check_positive_int(workers, "workers")
    if executor is None:
        return executor_for(workers, scheduler)
    if workers != 1 or scheduler is not None:
        raise ValueError(f"give `executor` ({executor!r}) or `workers`/`scheduler`, not both")
    return executor


def _open_out(out: str | os.PathLike, executor: Executor, *, lasting: bool) -> Store:
    """The run's output, refused before any work when it lives in this process only
    (``memory://``) and must outlive it (``lasting``: the command line) or be written by
    other processes (``workers > 1``)."""
    from .executors import ProcessPool

    store = open_store(out)  # an unknown URL protocol fails here, before any work
    if store.process_local and lasting:
        raise ValueError(
            f"`--out` {out!r} is a filesystem inside this process: "
            "everything written there is gone when the command exits; give a "
            "folder or a URL that outlives it (file://, s3://, ...)"
        )
    if store.process_local and isinstance(executor, ProcessPool) and executor.workers > 1:
        raise ValueError(
            f"`out` {store.name!r} lives in this process only, so the "
            f"{executor.workers} "
            "`workers` processes could not write their items into it: use "
            "workers=1, a folder, or a URL every process reaches (file://, s3://)"
        )
    return store


def _make(
    cfg: Config, store: Store, out: str | os.PathLike, executor: Executor, seed: int | None, progress: bool | None
) -> RunSummary:
    """:func:`run` once its options are checked and its output opened."""
    from ao4d import _progress
    from ao4d._validate import check_positive_int

    executor.check()  # a scheduler address that is no scheduler: before the output is touched
    seed = cfg.seed if seed is None else check_positive_int(seed, "seed", minimum=0)
    device_name()  # an impossible AO4D_DEVICE fails here, before the folder is touched
    backend = resolved_backend(cfg.backend)  # once per run: every item computes on it
    splits = None if cfg.split is None else split_counts(cfg.split, seed, cfg.n_items)
    if splits and empty_splits(splits):  # said before any work: the user may rather change the fractions
        warnings.warn(empty_split_message(cfg, seed, splits), UserWarning, stacklevel=3)
    claim_out(store, cfg, seed)
    run_sha256 = store.sha256("run.json")
    items = cfg.items()
    summary = RunSummary(out if is_url(out) else Path(out), len(items))
    start = time.perf_counter()
    todo = []
    for spec in items:
        if item_complete(store, spec.index):
            summary.skipped += 1
        else:
            todo.append(Job(spec, seed, str(out), backend, run_sha256, split_of(cfg.split, seed, spec.index)))
    foreign = {}  # files no run writes in folders of items to be remade: kept, and said so
    for job in todo:
        names = foreign_files(store, job.spec.index, [r["name"] for r in job.spec.family.settings["renders"]])
        if names:
            foreign[job.spec.index] = names
    if foreign:
        shown = "; ".join(f"items/{i:05d}: {', '.join(names)}" for i, names in list(foreign.items())[:5])
        more = f" and {len(foreign) - 5} more items" if len(foreign) > 5 else ""
        warnings.warn(
            f"`out` {store.name!r}: items to be remade hold files this run does not write ({shown}{more}); "
            "they are left as they are (not hashed in the manifest)",
            UserWarning,
            stacklevel=3,
        )

    # on a terminal a bar; in a log a line every few seconds (items take seconds to minutes)
    bar = _progress.bar(
        len(items),
        f"{cfg.name} items",
        unit="item",
        initial=summary.skipped,
        show=True if progress is None else bool(progress),
    )
    try:
        if todo:
            executor.make(todo, store, summary, bar)
    except KeyboardInterrupt:
        bar.close()
        print(
            f"\ninterrupted: finished items are kept; rerun the same command to resume "
            f"({summary.made + summary.skipped} of {len(items)} complete)",
            file=sys.stderr,
        )
        raise
    bar.close()
    summary.seconds = time.perf_counter() - start
    try:
        ours = store.sha256("run.json") == run_sha256
    except OSError:
        ours = False
    if not ours:  # another run wrote its own run.json meanwhile, or it was removed
        check_same_run(store, cfg, seed)
    try:
        summary.bytes = write_index(store, items, summary, splits=splits)
    except OSError as exc:  # a full disk, a lost mount: the items already written are kept
        raise ValueError(
            f"cannot write the index of `out` {store.name!r} "
            f"({getattr(exc, 'filename', None) or 'items.csv, manifest.json'}): "
            f"{exc.strerror or exc}; the finished items are kept: make room and "
            "rerun the same command to finish"
        ) from None
    return summary


def empty_split_message(cfg: Config, seed: int, splits: dict[str, int]) -> str:
    """The warning for splits of ``cfg`` that get no item of the run (``splits``: the counts)."""
    empty = empty_splits(splits)
    table = ", ".join(f"{name} = {frac:g}" for name, frac in (cfg.split or {}).items())
    counts = ", ".join(f"{name} {count}" for name, count in splits.items())
    return (
        f"`split` {{ {table} }}: split(s) {', '.join(map(repr, empty))} get no item of the "
        f"{cfg.n_items} items with seed {seed} (items per split: {counts}); they exist but are "
        "empty (summary.json lists them under empty_splits): raise their fraction or the count "
        "if they should hold items"
    )


def _usage_error(config: str) -> str:
    """The message for a ``CONFIG`` that is neither a file nor a shipped configuration: a word
    such as ``run`` or ``resume`` is no subcommand here."""
    from .config import shipped_configs

    return (
        f"no config {config!r}: neither a file nor a shipped config "
        f"({', '.join(shipped_configs())}); usage: python -m datasets_gen CONFIG --out DIR "
        "[--workers N | --scheduler ADDRESS|local:N] [--seed S] (rerun the same command to "
        "resume), or python -m datasets_gen export DIR --format webdataset|parquet --out OUT"
    )


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m datasets_gen CONFIG --out DIR [--workers N | --scheduler
    ADDRESS|local:N] [--seed S]``."""
    import argparse

    from ao4d.opencl.cl import NoOpenCLDeviceError

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
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("config", nargs="?", help="a TOML file or the name of a shipped config")
    parser.add_argument(
        "--out",
        help="output folder (created; reruns resume), or an fsspec URL "
        "(s3://bucket/run, file:///shared/run) that the workers "
        "write their items into; required unless --list",
    )
    parser.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS|local:N",
        help="run the items on a dask.distributed scheduler (an address such as "
        "tcp://head:8786, or local:N for a LocalCluster of N processes)",
    )
    parser.add_argument("--seed", type=int, default=None, help="run seed (default: the config's)")
    parser.add_argument("--list", action="store_true", help="show the items' families and exit")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--kinds", action="store_true", help="list the family kinds and their parameters, and exit")
    args = parser.parse_args(argv)
    if args.kinds:
        from .families import kinds

        for name, kind in kinds().items():
            print(f"{name}({', '.join(kind.params)})\n    {kind.doc.splitlines()[0].strip()}")
        return 0
    if args.config is None:
        parser.error("the following arguments are required: config")
    try:
        # the config first: `python -m datasets_gen run` names no config, whatever --out says
        try:
            cfg = load_config(args.config)
        except FileNotFoundError:
            print(f"error: {_usage_error(args.config)}", file=sys.stderr)
            return 2
        if args.list:  # counts only: listing every item of a large run builds nothing
            print(f"{cfg.name} ({cfg.source}): {cfg.n_items} items\n{describe(cfg)}")
            return 0
        if args.out is None:
            parser.error("the following arguments are required: --out")
        executor = _executor(args.workers, args.scheduler, None)
        store = _open_out(args.out, executor, lasting=True)
        if args.no_progress:
            from ao4d import _progress

            _progress.set_enabled(False)
        with warnings.catch_warnings():
            # warnings (an empty split, foreign files kept) as plain lines, each when it happens
            warnings.simplefilter("always", UserWarning)
            warnings.showwarning = _show_warning
            summary = _make(cfg, store, args.out, executor, args.seed, False if args.no_progress else None)
    except (FileNotFoundError, FileExistsError, ConfigError, ValueError, TypeError, NoOpenCLDeviceError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    print(summary)
    return 1 if summary.failed else 0


def _show_warning(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
    """Print a warning as ``warning: <message>`` on stderr (no source line, no file name)."""
    print(f"warning: {message}", file=sys.stderr if file is None else file)
