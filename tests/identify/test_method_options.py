"""The method contract's option half (issue 19): every registered method declares its
options once (maglevid.identify.options), and validation, the CLI's typed
``--option`` and ``--method list`` all come from that declaration.

Reference values: the declarations themselves and the fit functions' signatures
(the declared defaults must be the signatures' ones); no numerical result here.
"""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.options import KINDS, Option, check_options, parse_cli_options
from maglevid.identify.pem import fit_pem
from maglevid.identify.registry import available_methods, get_method, method_options

METHODS = sorted(available_methods())


@pytest.mark.parametrize("method", METHODS)
def test_every_registered_method_declares_its_options(method):
    declared = method_options(method)
    assert declared, f"{method} registers no option declaration"
    fit = available_methods()[method]
    params = inspect.signature(fit).parameters
    keywords = {n: p for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    names = [o.name for o in declared]
    assert len(set(names)) == len(names)
    if keywords:  # an explicit signature: the declaration names exactly its keywords
        assert set(names) == set(keywords), method
        for o in declared:  # and the defaults are the signature's (written once)
            assert o.default == keywords[o.name].default or o.name == "dt", (method, o.name)
    for o in declared:
        assert o.kind in KINDS and o.doc and "\n" not in o.doc, (method, o)
        if o.default is not None and o.kind != "object":
            o.check(o.default)  # every default is a valid value of its own declaration


def _record(n=400) -> ClosedLoopData:
    # Only the option checks are exercised: they come before any use of the data.
    rng = np.random.default_rng(0)
    r = rng.standard_normal(n)
    return ClosedLoopData(y=rng.standard_normal(n), u=r, r=r, u_f=np.zeros(n), dt=1e-3)


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (
            {"strucure": "oe"},
            "method 'pem' has no option 'strucure' (did you mean 'structure'?); its options: ",
        ),
        ({"na": 2.5}, "pem: `na` must be an integer >= 1; got 2.5"),
        ({"na": True}, "pem: `na` must be an integer >= 1; got True"),
        ({"nk": -1}, "pem: `nk` must be an integer >= 0; got -1"),
        ({"structure": "bj"}, "pem: `structure` must be one of 'arx', 'armax', 'oe'; got 'bj'"),
        ({"intercept": "yes"}, "pem: `intercept` must be true or false; got 'yes'"),
        ({"segments": [[0, 10, 20]]}, "pem: `segments` must be a list of [start, stop]"),
        ({"max_nfev": 0}, "pem: `max_nfev` must be an integer >= 1 or None; got 0"),
    ],
)
def test_invalid_options_give_one_clear_error(options, expected):
    with pytest.raises(DataError) as exc:
        get_method("pem")(_record(), **options)
    text = str(exc.value)
    assert text.startswith(expected) and "\n" not in text, text


def test_direct_calls_are_validated_by_the_same_declaration():
    # fit_pem itself (not through the registry) names itself and the option.
    with pytest.raises(DataError, match=r"^fit_pem: `k_step` must be an integer >= 1; got 0$"):
        fit_pem(_record(), k_step=0)


def test_every_method_refuses_an_unknown_option_in_one_line():
    data = _record()
    for method in METHODS:
        with pytest.raises(DataError, match=f"method '{method}' has no option 'no_such'") as exc:
            get_method(method)(data, no_such=1)
        # As Python's own unexpected keyword: existing `except TypeError` still catches it.
        assert isinstance(exc.value, TypeError)


def test_ranges_and_open_bounds():
    m = Option("m", "float", "mass", low=0, low_open=True, unit="kg")
    check_options("x", [m], {"m": 0.5})
    check_options("x", [m], {"m": np.float64(2)})
    for bad in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(DataError, match=r"`m` must be a number > 0"):
            check_options("x", [m], {"m": bad})
    laws = Option("laws", "strs", "laws", choices=("a", "b"), default=("a",))
    check_options("x", [laws], {"laws": ["b", "a"]})
    with pytest.raises(DataError, match="a list of one of 'a', 'b'"):
        check_options("x", [laws], {"laws": ["c"]})
    with pytest.raises(DataError, match="a list of one of"):
        check_options("x", [laws], {"laws": "a"})  # a text is not a list of texts


def test_cli_option_values_are_typed_by_the_declaration():
    declared = method_options("pem")
    out = parse_cli_options(
        "pem", declared,
        ["na=3", "intercept=false", "output=y:0", "segments=[[0, 100]]", "max_nfev=none"],
    )  # fmt: skip
    assert out == {"na": 3, "intercept": False, "output": "y:0", "segments": [[0, 100]],
                   "max_nfev": None}  # fmt: skip
    assert type(out["na"]) is int and type(out["intercept"]) is bool
    ind = parse_cli_options("indirect", method_options("indirect"),
                            ["controller_inputs=r:0,y:0,y:1"])  # fmt: skip
    assert ind == {"controller_inputs": ["r:0", "y:0", "y:1"]}
    with pytest.raises(DataError, match=r"--option 'na=3.5': method 'pem' takes an integer"):
        parse_cli_options("pem", declared, ["na=3.5"])
    with pytest.raises(DataError, match="takes true or false for `intercept`"):
        parse_cli_options("pem", declared, ["intercept=maybe"])
    with pytest.raises(DataError, match=r"`na` must be an integer >= 1; got 0"):
        parse_cli_options("pem", declared, ["na=0"])  # typed, then range-checked


def test_cli_rejects_a_mistyped_option_in_one_line(tmp_path, capsys):
    from maglevid.io import write_recording

    rec = write_recording(_record(), tmp_path / "r.npz")
    code = main(["identify", str(rec), "--method", "pem", "--option", "na=two"])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and "Traceback" not in err
    assert "--option 'na=two': method 'pem' takes an integer >= 1 for `na`" in err


def test_method_list_shows_every_method_with_its_options(capsys):
    assert main(["--json", "identify", "x.npz", "--method", "list"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert set(listed["options"]) == set(METHODS)
    pem = {o["name"]: o for o in listed["options"]["pem"]}
    assert pem["na"] == {"name": "na", "kind": "int", "doc": pem["na"]["doc"], "default": 2,
                         "range": [1, None]}  # fmt: skip
    assert pem["structure"]["choices"] == ["arx", "armax", "oe"]
    greybox = {o["name"]: o for o in listed["options"]["greybox-levitator"]}
    assert greybox["m"]["unit"] == "kg" and greybox["m"]["low_open"] is True
    assert main(["identify", "x.npz", "--method", "list"]) == 0
    text = capsys.readouterr().out
    assert "\n    na: int = 2 " in text and "{arx, armax, oe}" in text
    assert "(0, inf) [kg]" in text


def test_declared_options_are_in_the_docstring():
    doc = inspect.getdoc(fit_pem)
    assert "\nOptions\n-------\noutput : channel, default 'y:0'\n" in doc
    assert "\nna : int, default 2\n    order of A (of F for oe); an integer >= 1.\n" in doc


def test_list_options_take_comma_separated_values_on_the_command_line():
    # `--option command_delay=false` for a list of booleans was refused ("must be a
    # list of true/false"): only JSON `[false]` parsed. Comma lists parse like the
    # channel lists do.
    from maglevid.identify.options import Option

    assert Option("x", "bools", "d").parse("false") == [False]
    assert Option("x", "bools", "d").parse("false,true") == [False, True]
    assert Option("x", "bools", "d").parse("[true]") == [True]
    assert Option("x", "floats", "d").parse("0.1, 2") == [0.1, 2.0]
    with pytest.raises(ValueError):
        Option("x", "bools", "d").parse("maybe")
