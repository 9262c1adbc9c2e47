"""datasets_gen: reproducible procedural 4D datasets for ao4d, and the experiments behind its numbers.

``python -m datasets_gen CONFIG --out DIR [--workers N] [--seed S]`` makes every item of a
configuration (a TOML file or a shipped name: see :func:`shipped_configs`): its closed 4D mesh,
ambient occlusion, optional renders and a JSON record, plus a ``manifest.json`` of sha256
hashes. The same configuration and seed give byte-identical files; an interrupted run resumes.

``datasets_gen.load(DIR)`` reads a dataset (or an export of one) back for training
(:mod:`datasets_gen.loader`), with fixed-size items from
:class:`datasets_gen.transforms.SubsamplePoints` and batches from :func:`datasets_gen.collate`;
``python -m datasets_gen export DIR --format webdataset|parquet --out OUT`` writes shards.

``python -m datasets_gen.experiments.<name> --out DIR [--quick]`` regenerates a table (CSV)
and figure (PNG) of the README.

Making datasets needs extras of ao4d: ``pip install "ao4d[datasets]"`` (libigl for sweeps of mesh
sequences, threadpoolctl for the workers' thread limits) and ``"ao4d[dask]"`` for
``--scheduler``; reading one back needs neither.

Example
-------
>>> from datasets_gen import load_config
>>> cfg = load_config("smoke")
>>> len(cfg.items()) > 0
True
"""

from __future__ import annotations

from . import transforms
from .batching import collate
from .config import Config, ConfigError, load_config, shipped_configs
from .index import RunSummary
from .items import item_seed
from .loader import Dataset, DatasetError, load
from .runner import run

__all__ = [
    "run",
    "RunSummary",
    "load_config",
    "shipped_configs",
    "Config",
    "ConfigError",
    "item_seed",
    "load",
    "Dataset",
    "DatasetError",
    "collate",
    "transforms",
]
