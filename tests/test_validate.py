"""Shared input validation: errors name the parameter."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize(
    ("value", "error", "message"),
    [(np.nan, ValueError, "`x` must be finite"), (np.inf, ValueError, "`x` must be finite"),
     ("one", TypeError, "`x` must be a real number"), (None, TypeError, "`x` must be a real number")],
)
def test_as_finite_float_names_the_parameter(value, error, message):
    from ao4d._validate import as_finite_float

    with pytest.raises(error, match=message):
        as_finite_float(value, "x")
    assert as_finite_float(np.float32(2.5), "x") == 2.5
