"""Every plot function is importable from maglevid.plotting (issue 18)."""

from __future__ import annotations

import inspect

import pytest

import maglevid.plotting


@pytest.mark.parametrize("name", maglevid.plotting.__all__)
def test_plot_function_exported(name):
    fn = getattr(maglevid.plotting, name)
    assert inspect.isfunction(fn) and fn.__name__ == name
    assert name in dir(maglevid.plotting)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="plot_nothing"):
        maglevid.plotting.plot_nothing  # noqa: B018
