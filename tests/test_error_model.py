"""The packet-error model: PER formulas per unit, accuracy for tiny rates, sanitising, shapes."""

from __future__ import annotations

import math
import re
import warnings
from decimal import Decimal, localcontext

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwsimnet_zenoh.phy.error import NO_LOSS, RateErrorModel
from uwsimnet_zenoh.phy.expr import ExprError, compile_expr

D = np.array([1.0, 10.0, 100.0])

# A constant rate and the same rate through m (to exercise the evaluated path as well as the short cut).
SAME_RATE = [("1e-3", 1.0), ("1e-4*m", 10.0)]


@pytest.mark.parametrize(("expr", "d"), SAME_RATE)
def test_bit_unit(expr: str, d: float) -> None:
    per = RateErrorModel(expr, "bit").per(np.array([d]), 10)
    assert per[0] == pytest.approx(1 - 0.999**80, rel=1e-12)  # 0.0769206...
    assert per[0] == pytest.approx(0.07692060216, rel=1e-9)


@pytest.mark.parametrize(("expr", "d"), SAME_RATE)
def test_byte_unit(expr: str, d: float) -> None:
    per = RateErrorModel(expr, "byte").per(np.array([d]), 10)
    assert per[0] == pytest.approx(1 - 0.999**10, rel=1e-12)  # 0.00995512...
    assert per[0] == pytest.approx(0.009955119790, rel=1e-9)


@pytest.mark.parametrize(("expr", "d"), SAME_RATE)
def test_packet_unit(expr: str, d: float) -> None:
    per = RateErrorModel(expr, "packet").per(np.array([d]), 10)
    assert per[0] == pytest.approx(1e-3, rel=1e-12)
    assert RateErrorModel(expr, "packet").per(np.array([d]), 5000)[0] == per[0]  # size does not matter


def test_bit_unit_over_distance() -> None:
    per = RateErrorModel("1e-5*m", "bit").per(D, 100)
    want = [1 - (1 - 1e-5 * d) ** 800 for d in D]
    np.testing.assert_allclose(per, want, rtol=1e-10)


@pytest.mark.parametrize("expr", ["1e-15", "1e-15 + 0*m", "1e-16*m"])
def test_tiny_rate_is_not_lost_to_rounding(expr: str) -> None:
    per = RateErrorModel(expr, "bit").per(np.array([10.0]), 100)
    assert per[0] == pytest.approx(800e-15, rel=1e-6)
    # Why the careful form: the textbook one is off by 0.08% here, because 1 - 1e-15 rounds.
    naive = 1 - (1 - 1e-15) ** 800
    assert abs(naive / 800e-15 - 1) > 5e-4


def test_tiny_rate_byte_unit() -> None:
    assert RateErrorModel("1e-15", "byte").per(np.array([1.0]), 100)[0] == pytest.approx(100e-15, rel=1e-6)


def test_rate_of_one_loses_everything() -> None:
    for unit in ("bit", "byte", "packet"):
        assert RateErrorModel("1", unit).per(D, 20).tolist() == [1.0, 1.0, 1.0]
        assert RateErrorModel("m/m", unit).per(D, 20).tolist() == [1.0, 1.0, 1.0]


@pytest.mark.parametrize(("expr", "d", "rate"), [
    ("2", 1.0, 1.0),                  # above 1
    ("m - 5", 10.0, 1.0),
    ("m - 5", 5.5, 0.5),
    ("-1", 1.0, 0.0),                 # negative
    ("m - 5", 0.0, 0.0),
    ("1/(m-3)", 3.0, 1.0),            # +inf
    ("1/(m-3)", 2.0, 0.0),            # -1
    ("-1/(m-3)", 3.0, 0.0),           # -inf
    ("0/(m-3)", 3.0, 1.0),            # nan
    ("log(m)", 0.0, 0.0),             # -inf
    ("sqrt(m - 5)", 1.0, 1.0),        # nan
    ("exp(m)", 1e4, 1.0),             # overflow to +inf
    ("-exp(m)", 1e4, 0.0),
    ("0/0", 1.0, 1.0),                # constant nan
    ("1e999", 1.0, 1.0),              # constant +inf
    ("-1e999", 1.0, 0.0),
])
def test_sanitising(expr: str, d: float, rate: float) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = RateErrorModel(expr, "packet")
        assert model.rate(np.array([d])).tolist() == [rate]
        assert model.per(np.array([d]), 10).tolist() == [rate]
        bit = RateErrorModel(expr, "bit").per(np.array([d]), 10)[0]
    assert bit == pytest.approx(1 - (1 - rate) ** 80, abs=1e-15)


def test_rate_mixed_array() -> None:
    model = RateErrorModel("1/(m-3)", "packet")
    np.testing.assert_array_equal(model.rate(np.array([3.0, 2.0, 4.0, 5.0])), [1.0, 0.0, 1.0, 0.5])


@pytest.mark.parametrize("expr", ["0.01*m", "0.5", "0"])
@pytest.mark.parametrize("unit", ["bit", "byte", "packet"])
def test_shapes_are_preserved(expr: str, unit: str) -> None:
    model = RateErrorModel(expr, unit)  # type: ignore[arg-type]
    for d in (np.linspace(0, 50, 6).reshape(2, 3), np.array([]), np.array(7.0), np.arange(4.0)):
        for out in (model.per(d, 32), model.rate(d)):
            assert isinstance(out, np.ndarray) and out.shape == d.shape and out.dtype == np.float64
            assert ((out >= 0) & (out <= 1)).all()
    assert model.per(3.0, 32).shape == ()  # a plain float works too


def test_input_is_not_modified() -> None:
    d = np.array([0.2, 0.5])
    for unit in ("bit", "byte", "packet"):
        model = RateErrorModel("m", unit)  # type: ignore[arg-type]
        out = model.per(d, 1)
        out[:] = -1.0
        model.rate(d)[:] = -1.0
    assert d.tolist() == [0.2, 0.5]


def test_no_loss() -> None:
    assert NO_LOSS.unit == "packet" and NO_LOSS.lossless
    out = NO_LOSS.per(np.ones((2, 3)), 1000)
    assert out.shape == (2, 3) and not out.any()
    assert RateErrorModel("0", "bit").lossless and RateErrorModel("0*5", "bit").lossless
    assert not RateErrorModel("0*m", "bit").lossless  # not known constant: 0*inf is nan
    assert not RateErrorModel("1e-9", "bit").lossless


def test_zero_size_frame() -> None:
    assert RateErrorModel("1", "bit").per(D, 0).tolist() == [0.0, 0.0, 0.0]
    assert RateErrorModel("m/m", "byte").per(D, 0).tolist() == [0.0, 0.0, 0.0]
    assert RateErrorModel("m/m", "packet").per(D, 0).tolist() == [1.0, 1.0, 1.0]


def test_construction() -> None:
    ex = compile_expr("0.01*m")
    model = RateErrorModel(ex, "packet")
    assert model.expr is ex
    np.testing.assert_allclose(model.per(D, 1), [0.01, 0.1, 1.0])
    assert repr(model) == "RateErrorModel('0.01*m', 'packet')"
    with pytest.raises(ValueError, match="unknown error-rate unit 'bits'"):
        RateErrorModel("0", "bits")  # type: ignore[arg-type]
    with pytest.raises(ExprError, match="unknown name 'x' at column 1"):
        RateErrorModel("x", "bit")
    with pytest.raises(TypeError):
        RateErrorModel(0.5, "bit")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="frame size"):
        model.per(D, -1)
    with pytest.raises(ValueError, match="frame size"):
        model.per(D, math.nan)  # type: ignore[arg-type]


def _exact_per(r: float, n: int) -> float:
    """1 - (1 - r)^n in 80-digit decimal arithmetic: the reference the float formula must meet."""
    if n == 0:
        return 0.0  # Decimal refuses 0 ** 0
    with localcontext() as ctx:
        ctx.prec = 80
        return float(1 - (1 - Decimal(r)) ** n)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.just(0.0), st.floats(min_value=1e-30, max_value=1.0)),
       st.integers(min_value=0, max_value=2000), st.sampled_from(["bit", "byte"]))
def test_per_against_exact_arithmetic(r: float, size: int, unit: str) -> None:
    n = size * (8 if unit == "bit" else 1)
    want = _exact_per(r, n)
    for expr in (repr(r), f"{r!r} + 0*m"):
        got = RateErrorModel(expr, unit).per(np.array([1.0, 2.0]), size)  # type: ignore[arg-type]
        np.testing.assert_allclose(got, [want, want], rtol=1e-9, atol=1e-300)


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=0, max_value=1e-2), st.integers(min_value=1, max_value=500))
def test_per_grows_with_size(r: float, size: int) -> None:
    model = RateErrorModel(f"{r!r}*m", "bit")
    d = np.array([0.0, 0.5, 1.0])
    small, big = model.per(d, size), model.per(d, size + 1)
    assert (small <= big).all() and (big <= 1).all() and small[0] == 0.0


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.floats(min_value=0.0, allow_nan=False, allow_infinity=False).map(repr),
                 st.from_regex(r"\A[ \t]?(?:[0-9]{1,4}\.?[0-9]{0,3}|\.[0-9]{1,3})(?:[eE][+-]?[0-9]{1,3})?[ \t]?\Z"),
                 st.sampled_from(["-1", "1e", "inf", "nan", "1_0", "+1", "0x1", "1e-3*m", "", " ", "1..2", "(1)"])),
       st.sampled_from(["bit", "byte", "packet"]))
def test_a_plain_number_is_the_constant_phy_expr_folds(text: str, unit: str) -> None:
    """A rate that is one number is read without phy.expr (and numpy): the same constant, the same
    losses, the same errors as the compiled expression gives."""
    try:
        ex = compile_expr(text)
    except ExprError as e:
        with pytest.raises(ExprError, match=re.escape(str(e))):
            RateErrorModel(text, unit)  # type: ignore[arg-type]
        return
    model, ref = RateErrorModel(text, unit), RateErrorModel(ex, unit)  # type: ignore[arg-type]
    assert model.lossless == ref.lossless and repr(model) == repr(ref)
    assert model.per(D, 40).tolist() == ref.per(D, 40).tolist()
    assert model.expr == ex
