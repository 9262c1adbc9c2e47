"""Dataset configurations: TOML files naming shape families, parameter distributions and settings.

A configuration (see ``datasets_gen/configs/*.toml``)::

    name = "tori"
    seed = 0                      # default run seed (--seed overrides)
    split = { train = 0.8, val = 0.1, test = 0.1 }   # optional: datasets_gen.splits

    [defaults]                    # settings every family inherits (each may override them)
    grid = 32                     # grid points across the widest axis of the fitted box
    method = "cubes"              # extraction: "cubes" | "simplices"
    padding = 0.0                 # extra room around the shape's extent, a fraction of its width
    # bounds = [-1.5, 1.5]        # a fixed cube grid instead of the fitted box (cubic cells,
                                  # one cell of margin: datasets_gen.families.fitted_grid)
    rotation = "random"           # "none" | "random" (uniform in SO(4))
    ao = { samples = 64, max_distance = inf, at = "vertices" }   # or ao = false
                                  # or ao = { tolerance = 0.01 } (confidence = 0.95,
                                  # max_samples = 4096): each value within 0.01, ao.npz's `error`
    renders = [{ name = "front", shape = [32, 32, 32], samples = 32 }]   # projection, fov
    samples = { uniform = 16384, near_surface = 16384, sigmas = [0.01, 0.05], surface = 16384 }
                                  # samples.npz (datasets_gen.samples); default false
    sequence = { frames = 17, axis = "w" }   # sequence.npz (datasets_gen.sequence); default false

    [[family]]
    kind = "spheritorus"          # see datasets_gen.families.KINDS
    count = 10
    params = { R = { uniform = [0.6, 0.9] }, r = { uniform = [0.15, 0.3] } }

A parameter is a constant (number, string, bool, list) or one table naming a distribution:
``{uniform = [a, b]}``, ``{loguniform = [a, b]}``, ``{normal = [mean, std]}``,
``{integers = [lo, hi]}`` (both inclusive) or ``{choice = [v1, v2, ...]}``. Parameters are drawn
in sorted name order from the item's own generator, so an item depends only on (seed, index).

Limits, checked when the configuration is read, before anything is built: a run holds at most
:data:`MAX_ITEMS` items (every family's ``count`` together); every number is finite (except
``ao.max_distance``, which may be ``inf``) and never a bool (TOML's ``true`` is no number);
a distribution's range must be finite; ``ao.samples`` and a render's ``samples`` are at most
:data:`MAX_AO_SAMPLES`. A file must be UTF-8 (a byte-order mark is accepted).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ao4d.opencl.cl import BACKENDS

from ._checks import check_keys
from .samples import check_samples
from .sequence import check_sequence
from .splits import check_split

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "Config",
    "Family",
    "ItemSpec",
    "load_config",
    "config_text",
    "shipped_configs",
    "sample_params",
    "ConfigError",
    "MAX_ITEMS",
    "MAX_AO_SAMPLES",
]

#: the most items one run may hold (all families together): a run's index, manifest and item
#: list are built in memory, and a million items of even the smallest grid take days
MAX_ITEMS = 10**6
#: the most AO rays per point (``ao.samples``, a render's ``samples``): more only costs time
#: (the estimate's noise falls as 1/sqrt(samples); 65536 rays leave well under 0.5 %)
MAX_AO_SAMPLES = 1 << 16

DISTRIBUTIONS = ("uniform", "loguniform", "normal", "integers", "choice")
_TOP_KEYS = {"name", "description", "seed", "backend", "defaults", "family", "split"}
_SETTING_KEYS = {
    "grid",
    "method",
    "padding",
    "bounds",
    "rotation",
    "ao",
    "renders",
    "tetrahedra",
    "samples",
    "sequence",
}
_FAMILY_KEYS = _SETTING_KEYS | {"kind", "count", "params", "name"}
_AO_KEYS = {"samples", "max_distance", "at", "tolerance", "confidence", "max_samples"}
_AO_TOLERANCE_KEYS = ("tolerance", "confidence", "max_samples")  # only when given
_RENDER_KEYS = {"name", "shape", "samples", "projection", "fov"}
DEFAULTS: dict[str, Any] = {
    "grid": 24,
    "method": "cubes",
    "padding": 0.0,
    "bounds": None,
    "rotation": "none",
    "ao": {"samples": 64, "max_distance": math.inf, "at": "vertices"},
    "renders": [],
    "tetrahedra": "star",
    "samples": False,
    "sequence": False,
}


class ConfigError(ValueError):
    """A configuration file is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class Family:
    """One ``[[family]]`` table with the defaults merged in."""

    name: str
    kind: str
    count: int
    params: dict[str, Any]
    settings: dict[str, Any]


@dataclass(frozen=True)
class ItemSpec:
    """Item ``index`` of a run: the ``number``-th item of ``family``."""

    index: int
    family: Family
    number: int


@dataclass(frozen=True)
class Config:
    """A parsed, validated configuration.

    Attributes
    ----------
    name : str
    source : str
        Where it was read from (path or ``shipped:<name>``).
    text : str
        The TOML text (kept verbatim in the run's ``run.json``).
    seed : int
    backend : {"auto", "opencl", "numpy"}
    families : list of Family
    split : dict of str to float, optional
        The top-level ``split`` table (name -> fraction; :mod:`datasets_gen.splits`).
    """

    name: str
    source: str
    text: str
    seed: int
    backend: str
    families: list[Family] = field(default_factory=list)
    split: dict[str, float] | None = None

    @property
    def sha256(self) -> str:
        """Hash of the TOML text."""
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()

    @property
    def n_items(self) -> int:
        """How many items the run holds (without building :meth:`items`)."""
        return sum(fam.count for fam in self.families)

    def items(self) -> list[ItemSpec]:
        """Every item of the run, in index order.

        Returns
        -------
        list of ItemSpec
            The items' families, parameters and indices.
        """
        out: list[ItemSpec] = []
        for fam in self.families:
            base = len(out)
            out.extend([ItemSpec(base + n, fam, n) for n in range(fam.count)])
        return out


def shipped_configs() -> list[str]:
    """Names of the configurations shipped in ``datasets_gen/configs``.

    Returns
    -------
    list of str
        The names, sorted.
    """
    folder = resources.files("datasets_gen").joinpath("configs")
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_key(key: Any) -> str:
    key = str(key)
    return key if _BARE_KEY.fullmatch(key) else _toml_string(key, f"the key {key!r}")


def _toml_string(value: str, where: str) -> str:
    """A TOML basic string: JSON's escapes, and DEL escaped too (TOML forbids it raw)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate: no UTF-8 text, so no TOML file, holds it
        raise ConfigError(f"{where}: {value!r} is not valid Unicode text (a lone surrogate)") from None
    return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as the Python values TOML can hold (``np.float64(0.1)`` -> 0.1)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _toml_value(value: Any, where: str) -> str:
    value = _plain(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return _toml_string(value, where)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v, where) for v in value) + "]"
    if isinstance(value, Mapping):
        if not value:
            return "{}"
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v, f'{where}.{k}')}" for k, v in value.items()) + " }"
    raise ConfigError(f"{where}: a value of type {type(value).__name__} has no TOML form: {value!r}")


def config_text(data: Mapping[str, Any]) -> str:
    """The TOML text of a configuration given as a mapping (as ``tomllib`` would read it).

    Top-level keys first, then the ``[defaults]`` table and one ``[[family]]`` table per
    family, one ``key = value`` line per setting (tables within them written inline).

    Parameters
    ----------
    data : mapping
        The configuration: ``name``, ``seed``, ``defaults``, ``family`` (a list of tables)...

    Returns
    -------
    str
        The text; :func:`load_config` of the mapping parses it, so a run's ``run.json``
        holds a text that reproduces the run.

    Raises
    ------
    ConfigError
        A value that TOML cannot hold (None, an object), naming its key. numpy scalars and
        arrays are written as the Python numbers and lists they hold.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"`config` must be a mapping, got {type(data).__name__}")
    lines = [f"{_toml_key(k)} = {_toml_value(v, k)}" for k, v in data.items() if k not in ("defaults", "family")]

    def table(header: str, values: Any, where: str) -> None:
        if not isinstance(values, Mapping):
            raise ConfigError(f"{where} must be a table, got {type(values).__name__}")
        lines.extend(["", header])
        lines.extend(f"{_toml_key(k)} = {_toml_value(v, f'{where}.{k}')}" for k, v in values.items())

    if "defaults" in data:
        table("[defaults]", data["defaults"], "defaults")
    families = data.get("family", [])
    if not isinstance(families, (list, tuple)):
        raise ConfigError(f"`family` must be a list of tables, got {type(families).__name__}")
    for n, fam in enumerate(families):
        table("[[family]]", fam, f"family #{n + 1}")
    return "\n".join(lines) + "\n"


def load_config(config: str | Path | Mapping[str, Any]) -> Config:
    """Read and validate a configuration by path, by shipped name (``"smoke"``, ``"tori"``...)
    or as a mapping.

    Parameters
    ----------
    config : str, pathlib.Path or mapping
        A TOML file, the name of a shipped configuration (:func:`shipped_configs`), or the
        configuration as a mapping (written as TOML by :func:`config_text`: ``Config.text``).

    Returns
    -------
    Config
        The validated configuration.

    Raises
    ------
    FileNotFoundError
        Neither a file nor a shipped name.
    ConfigError
        Malformed TOML, unknown keys, bad values or distributions (the message says where).
    """
    if isinstance(config, Mapping):
        text = config_text(config)
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:  # a value TOML cannot hold, e.g. an integer past 2**63
            raise ConfigError(f"<mapping>: a value has no TOML form ({exc}); the config text was:\n{text}") from None
        return _parse(data, text, "<mapping>")
    if not isinstance(config, (str, Path)):
        raise ConfigError(
            f"`config` must be a TOML file's path, a shipped configuration's name or a mapping, "
            f"got {type(config).__name__}"
        )
    try:
        path = Path(config)
        is_file = path.is_file()
    except (OSError, ValueError) as exc:  # a NUL byte, a name too long for the filesystem
        raise FileNotFoundError(f"`config` {str(config)!r} cannot be a file ({exc})") from None
    if is_file:
        text, source = _read_text(path), str(path)
    else:
        name = str(config).removesuffix(".toml")
        if "/" in name or "\\" in name or not name or not _shipped(name):
            hint = " (it is a folder)" if path.is_dir() else ""
            raise FileNotFoundError(
                f"`config` {str(config)!r} is neither a file{hint} nor a shipped configuration "
                f"({', '.join(shipped_configs())})"
            )
        res = resources.files("datasets_gen").joinpath("configs", f"{name}.toml")
        text, source = res.read_text(encoding="utf-8"), f"shipped:{name}"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    return _parse(data, text, source)


def _shipped(name: str) -> bool:
    """Whether ``name`` is a shipped configuration (compared with the list: no path is built
    from an odd name)."""
    return name in shipped_configs()


def _read_text(path: Path) -> str:
    """The text of a configuration file: UTF-8, a byte-order mark (``utf-8-sig``) accepted."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the configuration file: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: a configuration file must be UTF-8 text; byte {exc.start} "
            f"({data[exc.start : exc.start + 1]!r}) is not UTF-8 (Latin-1 or another encoding?): "
            "save it as UTF-8"
        ) from None


def _parse(data: dict, text: str, source: str) -> Config:
    from .families import INTEGER_PARAMS, KINDS

    _no_unknown(data, _TOP_KEYS, source, "top level")
    for key in ("name", "description"):
        if key in data and (not isinstance(data[key], str) or not data[key].strip()):
            raise ConfigError(f"{source}: `{key}` must be a non-empty string, got {data[key]!r}")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{source}: `seed` must be an integer >= 0, got {seed!r}")
    backend = data.get("backend", "auto")
    if backend not in BACKENDS:
        raise ConfigError(f"{source}: `backend` must be one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    split = None
    if "split" in data:
        try:
            split = check_split(data["split"])
        except ValueError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    defaults = copy.deepcopy(DEFAULTS)
    user_defaults = data.get("defaults", {})
    _no_unknown(user_defaults, _SETTING_KEYS, source, "[defaults]")
    defaults.update(user_defaults)
    families = data.get("family")
    if not isinstance(families, list) or not families:
        raise ConfigError(f"{source}: needs at least one [[family]] table")
    parsed = []
    total = 0
    for n, fam in enumerate(families):
        where = f"[[family]] #{n + 1}"
        _no_unknown(fam, _FAMILY_KEYS, source, where)
        kind = fam.get("kind")
        if kind not in KINDS:
            raise ConfigError(f"{source}: {where}: `kind` must be one of {', '.join(KINDS)}; got {kind!r}")
        where = f"{where} ({kind})"
        if "name" in fam and (not isinstance(fam["name"], str) or not fam["name"].strip()):
            raise ConfigError(f"{source}: {where}: `name` must be a non-empty string, got {fam['name']!r}")
        count = fam.get("count", 1)
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_ITEMS:
            raise ConfigError(f"{source}: {where}: `count` must be an integer in [1, {MAX_ITEMS}], got {count!r}")
        total += count
        if total > MAX_ITEMS:  # checked before any item is listed: 10**8 specs alone take minutes
            raise ConfigError(
                f"{source}: the families' `count`s add up to {sum(f.get('count', 1) for f in families)!r} items; "
                f"a run holds at most {MAX_ITEMS} (datasets_gen.config.MAX_ITEMS): split it into several runs"
            )
        params = fam.get("params", {})
        allowed = KINDS[kind].params
        _no_unknown(params, set(allowed), source, f"{where} params of kind {kind!r}")
        for pname, spec in params.items():
            _check_distribution(spec, f"{source}: {where}: params.{pname}")
            if (kind, pname) in INTEGER_PARAMS:
                _check_integer_param(spec, INTEGER_PARAMS[kind, pname], f"{source}: {where}: params.{pname}")
        settings = copy.deepcopy(defaults)
        settings.update({k: v for k, v in fam.items() if k in _SETTING_KEYS})
        _check_settings(settings, f"{source}: {where}")
        parsed.append(Family(str(fam.get("name", kind)), kind, count, dict(params), settings))
    return Config(str(data.get("name", Path(source).stem)), source, text, seed, backend, parsed, split)


def _no_unknown(table: Any, allowed: set[str], source: str, where: str) -> None:
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: {where} must be a table, got {type(table).__name__}")
    try:
        check_keys(table, allowed, where)
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def _check_ao_tolerance(ao: Mapping[str, Any], where: str) -> None:
    """``ao.tolerance`` (with ``confidence`` and ``max_samples``) instead of ``ao.samples``:
    checked as :func:`ao4d.ambient_occlusion` checks them, before any work."""
    given = [k for k in _AO_TOLERANCE_KEYS if k in ao]
    if not given:
        return
    if "tolerance" not in ao:
        raise ConfigError(f"{where}: `ao.{given[0]}` is used only with `ao.tolerance`; give `ao.tolerance` too")
    if "samples" in ao:
        raise ConfigError(
            f"{where}: give `ao.samples` or `ao.tolerance`, not both (with a tolerance each vertex "
            "traces as many rays as it needs, at most `ao.max_samples`)"
        )
    tolerance, confidence = ao["tolerance"], ao.get("confidence", 0.95)
    for key, value in (("tolerance", tolerance), ("confidence", confidence)):
        if not _is_number(value) or not 0 < value < 1:
            raise ConfigError(f"{where}: `ao.{key}` must be a number in (0, 1), got {value!r}")
    from ao4d.ao import minimum_samples

    fewest = minimum_samples(tolerance, confidence)
    most = ao.get("max_samples", 4096)
    if isinstance(most, bool) or not isinstance(most, int) or not fewest <= most <= MAX_AO_SAMPLES:
        raise ConfigError(
            f"{where}: `ao.max_samples` must be an integer in [{fewest}, {MAX_AO_SAMPLES}] (at least "
            f"the fewest rays for tolerance={tolerance:g} at confidence={confidence:g}), got {most!r}"
        )


def _is_number(value: Any) -> bool:
    """An int or float, never a bool (``True`` is an int in Python, and no number in a config)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_finite(value: Any) -> bool:
    """A finite number (:func:`_is_number`)."""
    return _is_number(value) and math.isfinite(value)


def _check_settings(s: dict[str, Any], where: str) -> None:
    grid = s["grid"]
    if isinstance(grid, bool) or not isinstance(grid, int) or not 4 <= grid <= 512:
        raise ConfigError(f"{where}: `grid` must be an integer in [4, 512], got {grid!r}")
    if s["method"] not in ("cubes", "simplices"):
        raise ConfigError(f"{where}: `method` must be 'cubes' or 'simplices', got {s['method']!r}")
    if not _is_finite(s["padding"]) or not 0 <= s["padding"] <= 2:
        raise ConfigError(f"{where}: `padding` must be a number in [0, 2], got {s['padding']!r}")
    if s["bounds"] is not None:
        b = s["bounds"]
        if not (
            isinstance(b, list)
            and len(b) == 2
            and all(map(_is_finite, b))
            and b[0] < b[1]
            and math.isfinite(b[1] - b[0])
        ):
            raise ConfigError(f"{where}: `bounds` must be [lo, hi], finite numbers with lo < hi, got {b!r}")
    if s["rotation"] not in ("none", "random"):
        raise ConfigError(f"{where}: `rotation` must be 'none' or 'random', got {s['rotation']!r}")
    if s["tetrahedra"] not in ("star", "auto", "tetwild"):
        raise ConfigError(f"{where}: `tetrahedra` must be 'star', 'auto' or 'tetwild', got {s['tetrahedra']!r}")
    ao = s["ao"]
    if ao is not False:
        if ao is True:
            ao = s["ao"] = copy.deepcopy(DEFAULTS["ao"])
        _no_unknown(ao, _AO_KEYS, where, "ao")
        _check_ao_tolerance(ao, where)
        ao = s["ao"] = {**DEFAULTS["ao"], **ao}
        if (
            isinstance(ao["samples"], bool)
            or not isinstance(ao["samples"], int)
            or not 1 <= ao["samples"] <= MAX_AO_SAMPLES
        ):
            raise ConfigError(
                f"{where}: `ao.samples` must be an integer in [1, {MAX_AO_SAMPLES}], got {ao['samples']!r}"
            )
        if not _is_number(ao["max_distance"]) or not ao["max_distance"] > 0:  # inf: no limit
            raise ConfigError(f"{where}: `ao.max_distance` must be a number > 0 (or inf), got {ao['max_distance']!r}")
        if ao["at"] not in ("vertices", "simplices"):
            raise ConfigError(f"{where}: `ao.at` must be 'vertices' or 'simplices', got {ao['at']!r}")
    try:
        s["samples"] = check_samples(s["samples"])
        s["sequence"] = check_sequence(s["sequence"])
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    renders = s["renders"]
    if not isinstance(renders, list):
        raise ConfigError(f"{where}: `renders` must be a list of tables, got {renders!r}")
    names = set()
    for r in renders:
        _no_unknown(r, _RENDER_KEYS, where, "renders[]")
        name = r.get("name")
        if not isinstance(name, str) or not name.isidentifier() or name in names:
            raise ConfigError(f"{where}: every render needs a distinct identifier `name`, got {name!r}")
        names.add(name)
        if r.get("projection", "orthographic") not in ("orthographic", "perspective"):
            raise ConfigError(
                f"{where}: render {name!r}: `projection` must be 'orthographic' or "
                f"'perspective', got {r['projection']!r}"
            )
        shape = r.get("shape", [32, 32, 32])
        if not (
            isinstance(shape, list)
            and len(shape) == 3
            and all(isinstance(v, int) and not isinstance(v, bool) and 2 <= v <= 512 for v in shape)
        ):
            raise ConfigError(f"{where}: render {name!r}: `shape` must be 3 integers in [2, 512], got {shape!r}")
        samples = r.get("samples", 32)
        if isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= MAX_AO_SAMPLES:
            raise ConfigError(
                f"{where}: render {name!r}: `samples` must be an integer in [1, {MAX_AO_SAMPLES}], got {samples!r}"
            )
        fov = r.get("fov", 40.0)
        if not _is_finite(fov) or not 0 < fov < 180:
            raise ConfigError(f"{where}: render {name!r}: `fov` must be a number of degrees in (0, 180), got {fov!r}")


def _check_constant(value: Any, where: str) -> None:
    """A parameter's constant (or a ``choice`` entry): a string, a finite number or a list of
    them; no family parameter is a bool, and a NaN or inf would only fail every item later."""
    if isinstance(value, bool):
        raise ConfigError(f"{where}: must be a number or a string, got the bool {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{where}: must be finite, got {value!r}")
    if isinstance(value, list):
        for n, v in enumerate(value):
            _check_constant(v, f"{where}[{n}]")
    elif not isinstance(value, (int, float, str)):
        raise ConfigError(f"{where}: must be a number, a string or a list of them, got {value!r}")


def _check_distribution(spec: Any, where: str) -> None:
    if not isinstance(spec, dict):
        _check_constant(spec, where)
        return
    if len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
        raise ConfigError(f"{where}: a distribution is one key of {', '.join(DISTRIBUTIONS)}, got {sorted(spec)}")
    ((kind, args),) = spec.items()
    if kind == "choice":
        if not isinstance(args, list) or not args:
            raise ConfigError(f"{where}: `choice` needs a non-empty list, got {args!r}")
        for n, v in enumerate(args):
            _check_constant(v, f"{where}.choice[{n}]")
        return
    if not (isinstance(args, list) and len(args) == 2 and all(map(_is_finite, args))):
        raise ConfigError(f"{where}: `{kind}` needs two finite numbers, got {args!r}")
    a, b = args
    if kind == "normal":
        if b < 0:
            raise ConfigError(f"{where}: `normal` std must be >= 0, got {b}")
    elif kind == "integers":
        if not (isinstance(a, int) and isinstance(b, int) and a <= b):
            raise ConfigError(f"{where}: `integers` needs integers lo <= hi, got {args!r}")
    elif not a <= b or (kind == "loguniform" and a <= 0):
        raise ConfigError(f"{where}: `{kind}` needs {'0 < ' if kind == 'loguniform' else ''}a <= b, got {args!r}")
    elif not math.isfinite(b - a):  # numpy's uniform draws inf (or fails) over a range wider than a float
        raise ConfigError(f"{where}: `{kind}` needs a range b - a that is a finite float, got {args!r}")


def _check_integer_param(spec: Any, bounds: tuple[int, int], where: str) -> None:
    """A count of parts or steps (:data:`datasets_gen.families.INTEGER_PARAMS`): an integer in
    ``bounds``, or an ``integers`` / ``choice`` distribution of such integers."""
    lo, hi = bounds
    if isinstance(spec, dict):
        ((kind, args),) = spec.items()
        values = args if kind in ("integers", "choice") else None
    else:
        values = [spec]
    if values is None or not all(isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi for v in values):
        raise ConfigError(
            f"{where}: must be an integer in [{lo}, {hi}] (a constant, or drawn by `integers` or `choice`), got {spec!r}"
        )


def sample_params(specs: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """Draw every parameter (in sorted name order) from ``rng``; constants pass through.

    Returns plain Python values (float, int, str, list), ready for JSON.
    """
    out: dict[str, Any] = {}
    for name in sorted(specs):
        spec = specs[name]
        if not isinstance(spec, dict):
            out[name] = copy.deepcopy(spec)
            continue
        ((kind, args),) = spec.items()
        if kind == "uniform":
            out[name] = float(rng.uniform(*args))
        elif kind == "loguniform":
            out[name] = float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
        elif kind == "normal":
            out[name] = float(rng.normal(*args))
        elif kind == "integers":
            out[name] = int(rng.integers(args[0], args[1], endpoint=True))
        else:  # choice
            out[name] = copy.deepcopy(args[int(rng.integers(len(args)))])
    return out


def describe(config: Config) -> str:
    """One line per family: name, kind, count, grid."""

    def how(f: Family) -> str:
        if f.kind == "lifted":
            return f"lifted with ao4d.lift, caps cut by {f.settings['tetrahedra']!r}"
        if f.kind == "sweep":
            return "swept through time with ao4d.lift.sweep"
        if f.settings["bounds"] is not None:
            return f"grid {f.settings['grid']}^4 on {f.settings['bounds']}, {f.settings['method']}"
        return f"grid fitted, {f.settings['grid']} points across, {f.settings['method']}"

    return "\n".join(f"  {f.name}: {f.count} x {f.kind} ({how(f)})" for f in config.families)
