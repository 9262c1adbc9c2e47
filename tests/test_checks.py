"""Tests for datasets_gen._checks: unknown keys named, with the allowed ones, wherever they are read."""

from __future__ import annotations

import pytest

from datasets_gen import ConfigError, load_config
from datasets_gen._checks import check_keys
from datasets_gen.samples import check_samples
from datasets_gen.sequence import check_sequence


def test_unknown_keys_are_named_with_the_allowed_ones():
    check_keys({"a": 1}, ["a", "b"], "`t`")  # no error
    check_keys({}, (), "`t`")
    with pytest.raises(ValueError, match=r"^`t`: unknown key\(s\) 'c', 'd'; allowed: a, b$"):
        check_keys({"d": 1, "a": 2, "c": 3}, {"b", "a"}, "`t`")


@pytest.mark.parametrize(
    "read, where",
    [
        (lambda: check_samples({"uniform": 1, "colour": 2}), "`samples`"),
        (lambda: check_sequence({"frames": 2, "colour": 2}), "`sequence`"),
        (lambda: load_config({"family": [{"kind": "hypersphere", "ao": {"colour": 2}}]}), "ao"),
        (lambda: load_config({"defaults": {"colour": 2}, "family": [{"kind": "hypersphere"}]}), r"\[defaults\]"),
    ],
)
def test_every_table_names_its_unknown_keys(read, where):
    with pytest.raises(ValueError, match=rf"{where}: unknown key\(s\) 'colour'; allowed: "):
        read()


def test_the_config_reader_names_its_source():
    with pytest.raises(ConfigError, match=r"^<mapping>: \[\[family\]\] #1: unknown key\(s\) 'colour'"):
        load_config({"family": [{"kind": "hypersphere", "colour": 2}]})
