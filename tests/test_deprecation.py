"""Tests for ao4d/_deprecation.py: renamed parameters keep working, with a warning naming the new one."""

from __future__ import annotations

import warnings

import pytest

from ao4d._deprecation import DEPRECATED, renamed


def _f(a, *, blocks=None, size=DEPRECATED):
    return a, renamed("f", "size", size, "blocks", blocks, None)


def test_old_spelling_warns_naming_the_new_one_and_passes_the_value():
    with pytest.warns(DeprecationWarning, match=r"f\(\): the parameter `size` is now called `blocks`") as record:
        assert _f(1, size=5) == (1, 5)
    assert record[0].filename == __file__  # points at the caller's line


def test_new_spelling_and_defaults_are_silent():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _f(2, blocks=3) == (2, 3)
        assert _f(2) == (2, None)
    assert repr(DEPRECATED) == "<deprecated>"


def test_both_spellings_are_an_error():
    with pytest.raises(TypeError, match=r"f\(\) got both `blocks` and its old spelling `size`"):
        _f(1, size=5, blocks=6)
