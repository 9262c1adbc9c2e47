"""Small dataset configurations for the datasets_gen tests, as mappings.

``datasets_gen.load_config`` and ``datasets_gen.run`` take a mapping; :func:`write_config`
writes one as TOML (``datasets_gen.config.config_text``) for the command line. The suite's
tiny run (:data:`TINY`) is made once per session by the ``tiny_reference`` fixture
(tests/conftest.py).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest

from datasets_gen import run
from datasets_gen.config import config_text

# hypersphere parameters of the small configs: the radius drawn in [0.5, 0.8]
BALL = {"radius": {"uniform": [0.5, 0.8]}}
# a lifted box prism: an exact 4-volume
BOX_PRISM = {"shape": "box", "op": "prism", "size": 0.4}


def family(kind: str, count: int, params: dict[str, Any], **settings: Any) -> dict[str, Any]:
    """One ``[[family]]`` table."""
    return {"kind": kind, "count": count, **settings, "params": params}


def config(name: str, seed: int, families: list[dict], *, split: dict | None = None, **defaults: Any) -> dict[str, Any]:
    """A configuration on the numpy backend (no OpenCL build in spawned workers)."""
    data: dict[str, Any] = {"name": name, "seed": seed, "backend": "numpy"}
    if split is not None:
        data["split"] = split
    return {**data, "defaults": defaults, "family": families}


# A run small enough for tests (a few seconds): implicit, CSG and lifted items, AO, one render.
# The numpy AO backend spares every spawned worker an OpenCL kernel build; the OpenCL path is
# covered by the slow test on the shipped smoke config.
TINY = config(
    "tiny",
    3,
    [
        family("hypersphere", 2, {"radius": {"uniform": [0.6, 0.9]}}),
        family("tesseracts", 1, {"n": 2, "half": 0.4, "spread": 0.2}),
        family(
            "lifted",
            2,
            {"shape": "box", "op": {"choice": ["prism", "spin"]}, "size": {"uniform": [0.3, 0.5]}, "k": 5},
            rotation="none",
            renders=[{"name": "view", "shape": [8, 8, 8], "samples": 2}],
        ),
    ],
    grid=10,
    padding=0.15,
    rotation="random",
    ao={"samples": 4},
)
TINY_ITEMS = 5


def learning(
    name: str, seed: int, families: list[dict], *, split: dict, points: tuple[int, int, int], **defaults: Any
) -> dict[str, Any]:
    """A small learning dataset: grids of 7 points unless ``grid`` says otherwise, random rotations,
    4 AO samples, and ``points`` = (uniform, near-surface at sigma 0.02, surface) samples."""
    uniform, near, surface = points
    samples = {"uniform": uniform, "near_surface": near, "sigmas": [0.02], "surface": surface}
    settings = {"grid": 7, "padding": 0.15, "rotation": "random", "ao": {"samples": 4}, **defaults}
    return config(name, seed, families, split=split, **settings, samples=samples)


def made_once(data: dict[str, Any]):
    """A module-scoped ``dataset`` fixture: the dataset of ``data``, made once per test module."""

    @pytest.fixture(scope="module")
    def dataset(tmp_path_factory):
        return make(tmp_path_factory.mktemp(data["name"]), data)

    return dataset


def tiny(name: str = "tiny", **defaults: Any) -> dict[str, Any]:
    """:data:`TINY` under another name, with some defaults changed."""
    data = copy.deepcopy(TINY)
    data["name"] = name
    data["defaults"].update(defaults)
    return data


def write_config(folder: Path, data: dict[str, Any], name: str = "cfg.toml") -> Path:
    """Write ``data`` as a TOML file in ``folder``; return its path."""
    path = Path(folder) / name
    path.write_text(config_text(data), encoding="utf-8")
    return path


def make(folder: Path, data: dict[str, Any], **kwargs: Any) -> Path:
    """The dataset of ``data`` made in ``folder/out`` (nothing may fail); returns the folder."""
    out = Path(folder) / "out"
    summary = run(data, out, progress=False, **kwargs)
    assert not summary.failed, summary.failed
    return out
