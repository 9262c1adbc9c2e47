"""The index of a run: its ``run.json`` first, and at the end ``items.csv``, ``manifest.json``
and ``summary.json`` (:class:`RunSummary`).

``run.json`` (configuration text, seed, versions) is created before any item, exclusively: one
output holds one run, and a run refuses an output that holds another. ``manifest.json`` lists
the sha256 and size of every hashed file (everything but :data:`UNHASHED`) of the complete
items and the top level; ``timing.json`` and ``summary.json`` hold wall-clock data and are left
out, so two runs of the same configuration and seed have byte-identical manifests.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ._files import json_bytes
from ._store import Store
from .config import Config, ItemSpec
from .items import RUN_FORMAT, item_folder, versions
from .splits import empty_splits

__all__ = [
    "RunSummary",
    "AROUND_AO",
    "UNHASHED",
    "run_info",
    "claim_out",
    "check_same_run",
    "write_index",
    "device_name",
]

UNHASHED = ("timing.json", "summary.json", "manifest.json")


#: the stages around AO that the throughput target weighs against it (besides ``picture_*``)
AROUND_AO = ("check", "bvh", "write")


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
        lines.append(
            f"  {'items':<10} {total:9.2f} {total / self.made:9.3f} {100.0:6.1f}%  "
            f"(summed over {self.made} items; {self.items_per_minute:.1f} items/min wall)"
        )
        around = self.around_ao
        if around is not None:
            lines.append(
                f"  around AO (check, bvh, write, picture_*): {around['seconds']:.2f} s = "
                f"{around['ratio']:.2f} x the ao stage"
            )
        return "\n".join(lines)

    @property
    def around_ao(self) -> dict[str, float] | None:
        """The stages around AO (:data:`AROUND_AO`: mesh check, BVH, writing, pictures) against
        the AO stage: ``{"seconds": their sum, "ao": the AO stage's, "ratio": seconds / ao}``,
        summed over the items made; ``None`` when no item made AO.
        """
        ao = self.stages.get("ao", 0.0)
        if ao <= 0:
            return None
        around = sum(v for n, v in self.stages.items() if n in AROUND_AO or n.startswith("picture_"))
        return {"seconds": around, "ao": ao, "ratio": around / ao}

    @property
    def items_per_minute(self) -> float:
        """Items made per minute of wall-clock time (skipped items not counted)."""
        return 60.0 * self.made / self.seconds if self.seconds > 0 else math.nan

    def __str__(self) -> str:
        rate = f"{self.items_per_minute:.1f} items/min" if self.made else "nothing to make"
        lines = [
            f"{self.out}: {self.made} made, {self.skipped} skipped (already complete), "
            f"{len(self.failed)} failed of {self.n_items}; {self.seconds:.1f} s, {rate}, "
            f"{self.bytes / 2**20:.2f} MiB"
        ]
        lines += [f"  item {i}: {msg}" for i, msg in sorted(self.failed.items())]
        table = self.stage_table()
        return "\n".join(lines + ([table] if table else []))


def _read_run_info(store: Store) -> dict[str, Any]:
    """``run.json`` of the store, checked: a damaged one is an error naming the file."""
    where = f"{store.name.rstrip('/')}/run.json"
    try:
        info = json.loads(store.read_text("run.json"))
    except (OSError, ValueError) as exc:  # unreadable, not UTF-8, not JSON
        raise ValueError(
            f"`out` {store.name!r}: its run.json ({where}) is unreadable or damaged "
            f"({type(exc).__name__}: {exc}); it names the run the folder holds, so "
            "nothing can be resumed there: restore it, or choose another folder"
        ) from None
    if (
        not isinstance(info, dict)
        or not isinstance(info.get("config_sha256"), str)
        or isinstance(info.get("seed"), bool)
        or not isinstance(info.get("seed"), int)
    ):
        raise ValueError(
            f"`out` {store.name!r}: its run.json ({where}) is damaged (no "
            "config_sha256 and seed of a datasets_gen run); restore it, or choose "
            "another folder"
        )
    return info


def run_info(config: Config, seed: int) -> bytes:
    """The bytes of ``run.json`` for a run of ``config`` with ``seed``.

    Parameters
    ----------
    config : Config
    seed : int
        The run's configuration and seed.

    Returns
    -------
    bytes
        Canonical JSON: the configuration's name, source, text and hash, the seed, the
        versions (:func:`datasets_gen.items.versions`) and the item count; with a split table,
        also ``split``, the table (name -> fraction, every name of the config, including those
        that get no item), so a reader knows every split without parsing ``config_text``.
        Without one the bytes are as before (no ``split`` key).
    """
    info: dict[str, Any] = {
        "format": RUN_FORMAT,
        "config_name": config.name,
        "config_source": config.source,
        "config_sha256": config.sha256,
        "config_text": config.text,
        "seed": seed,
        "versions": versions(),
        "n_items": config.n_items,
    }
    if config.split is not None:
        info["split"] = dict(config.split)
    return json_bytes(info)


def check_same_run(store: Store, config: Config, seed: int) -> None:
    """Refuse a store whose ``run.json`` is of another config or seed (or damaged).

    Parameters
    ----------
    store, config, seed
        As for :func:`claim_out`.

    Raises
    ------
    FileExistsError
        ``run.json`` names another configuration text or seed.
    ValueError
        ``run.json`` is unreadable or damaged (the message names it).
    """
    previous = _read_run_info(store)
    if previous["config_sha256"] == config.sha256 and previous["seed"] == seed:
        return
    theirs = (
        f"config {previous.get('config_name')!r} with seed {previous['seed']} "
        f"({previous.get('config_source')}, text sha256 {previous['config_sha256'][:12]})"
    )
    ours = f"config {config.name!r} with seed {seed} ({config.source}, text sha256 {config.sha256[:12]})"
    why = (
        "the seeds differ"
        if previous["config_sha256"] == config.sha256
        else "the configs' texts differ"
        if previous.get("config_name") == config.name
        else "another config"
    )
    raise FileExistsError(
        f"`out` {store.name!r} holds a run of {theirs}, not of {ours} ({why}); one folder holds "
        "one run (that run may still be going): choose another folder, or delete it"
    )


def claim_out(store: Store, config: Config, seed: int) -> None:
    """Create ``run.json`` in ``store``, or accept one of the same run; refuse anything else.

    The creation is exclusive on a local folder, so of two runs started into one new folder
    at once, one is refused.

    Parameters
    ----------
    store : Store
        The run's output.
    config : Config
    seed : int
        The run's configuration and seed.

    Raises
    ------
    FileExistsError
        The output holds another run, or files but no ``run.json``.
    ValueError
        The output cannot be created or written, or its ``run.json`` is damaged.
    """
    out = store.name
    holds_something = store.prepare()
    if store.is_file("run.json"):
        check_same_run(store, config, seed)
        return
    if holds_something:
        raise FileExistsError(
            f"`out` {out!r} exists, is not empty and holds no run.json; choose an empty or new folder"
        )
    try:
        created = store.create_bytes("run.json", run_info(config, seed))
    except OSError as exc:  # a read-only file system, a full disk, no permission
        raise ValueError(f"cannot write into the output folder `out` {out!r}: {exc.strerror or exc}") from None
    if not created:  # another run created it since prepare() looked
        check_same_run(store, config, seed)


def write_index(
    store: Store, items: list[ItemSpec], summary: RunSummary, *, splits: dict[str, int] | None = None
) -> int:
    """Write ``items.csv``, ``manifest.json`` (hashes) and ``summary.json``.

    An item that ``summary`` counts as made but whose record the store does not hold is
    moved from the made to the failed ones.

    Parameters
    ----------
    store : Store
        The run's output.
    items : list of ItemSpec
        Every item of the run.
    summary : RunSummary
        What the run did.
    splits : dict of str to int, optional
        Items per split of the whole run (:func:`datasets_gen.splits.split_counts`, every
        name of the config's table): ``summary.json`` gets ``splits`` and ``empty_splits``
        (the names that get no item). Not given without a split table.

    Returns
    -------
    int
        The bytes of every hashed file.
    """
    records: dict[int, dict] = {}  # each complete item's record (never a failed or interrupted one)
    for spec in items:
        rel = item_folder(spec.index)
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
        rows.append(
            [
                int(index),  # a Python int: never a numpy integer that could print wrapped
                rec["family"],
                rec["kind"],
                m["vertices"],
                m["simplices"],
                m["check"]["ok"],
                repr(m["volume"]),
                repr(m["volume_expected"]),
                repr(m["volume_rel_error"]),
                repr(rec["ao"]["mean"]) if rec["ao"] else "",
                rec.get("split") or "",
            ]
        )
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(
        [
            "index",
            "family",
            "kind",
            "vertices",
            "simplices",
            "ok",
            "volume",
            "volume_expected",
            "volume_rel_error",
            "ao_mean",
            "split",
        ]
    )
    writer.writerows(rows)
    store.write_bytes("items.csv", text.getvalue().encode("utf-8"))

    # top-level files, and each complete item's record and the files it lists (never the
    # leftovers of a failed or interrupted item). Item files carry the hashes their record
    # holds (made when they were written, checked when a rerun found the item complete), so
    # no item's bytes are read here again: only the records'.
    known: dict[str, str | None] = {name: None for name in store.files()}
    for index, rec in records.items():
        rel = item_folder(index)
        known[f"{rel}/record.json"] = None
        for name, digest in rec["files"].items():
            known[f"{rel}/{name}"] = digest
    files = {}
    for rel in sorted(known):
        name = rel.rpartition("/")[2]
        if name not in UNHASHED and not name.startswith("."):
            files[rel] = {"sha256": known[rel] or store.sha256(rel), "bytes": store.size(rel)}
    info = json.loads(store.read_text("run.json"))
    store.write_bytes(
        "manifest.json",
        json_bytes(
            {
                "format": RUN_FORMAT,
                "config_sha256": info["config_sha256"],
                "seed": info["seed"],
                "n_items": len(items),
                "complete": len(rows) == len(items),
                "unhashed": list(UNHASHED),
                "files": files,
            }
        ),
    )
    size = sum(f["bytes"] for f in files.values())
    stats: dict[str, Any] = {
        "device": device_name(),
        "made": summary.made,
        "skipped": summary.skipped,
        "failed": summary.failed,
        "seconds": summary.seconds,
        "items_per_minute": summary.items_per_minute,
        "bytes": size,
        "stages": summary.stages,
        "around_ao": summary.around_ao,
    }
    if splits is not None:  # summary.json is not hashed: the manifest stays as it was
        stats["splits"] = dict(splits)
        stats["empty_splits"] = empty_splits(splits)
    store.write_bytes("summary.json", json_bytes(stats))
    return size


def device_name() -> str:
    """The OpenCL device ao4d would use here.

    AO values may differ in the last bits between devices, so a dataset is byte-reproducible
    on the same software and device; ``summary.json`` names it.

    Returns
    -------
    str
        The device's description (:func:`ao4d.opencl.cl.describe`).
    """
    from ao4d.opencl import cl

    return cl.describe(cl.resolve_backend("auto", warn=False))
