"""The error-rate expression parser: values, precedence, vectorisation, and the errors it must raise."""

from __future__ import annotations

import contextlib
import math
import pickle
import warnings
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uwsimnet_zenoh.phy.expr import MAX_DEPTH, MAX_LENGTH, Expr, ExprError, compile_expr

# (text, m, value computed by hand)
TABLE: list[tuple[str, float, float]] = [
    ("-2^2", 0.0, -4.0),
    ("-2**2", 0.0, -4.0),
    ("(-2)^2", 0.0, 4.0),
    ("2^3^2", 0.0, 512.0),
    ("(2^3)^2", 0.0, 64.0),
    ("2**3**2", 0.0, 512.0),
    ("2^-1", 0.0, 0.5),
    ("2**-1", 0.0, 0.5),
    ("2^-2^2", 0.0, 0.0625),  # 2^(-(2^2))
    ("-2^-2", 0.0, -0.25),
    ("2*3+4", 0.0, 10.0),
    ("2+3*4", 0.0, 14.0),
    ("(2+3)*4", 0.0, 20.0),
    ("10/4/5", 0.0, 0.5),
    ("10-4-3", 0.0, 3.0),
    ("10-(4-3)", 0.0, 9.0),
    ("2*3^2", 0.0, 18.0),
    ("-3*-2", 0.0, 6.0),
    ("- -3", 0.0, 3.0),
    ("+-+3", 0.0, -3.0),
    ("2 - -3", 0.0, 5.0),
    ("-m", 3.0, -3.0),
    ("m^2", 3.0, 9.0),
    ("-m^2", 3.0, -9.0),
    ("1/m", 4.0, 0.25),
    ("0.01*m", 250.0, 2.5),
    ("min(3,1,2)", 0.0, 1.0),
    ("max(3, 1, 2)", 0.0, 3.0),
    ("min(m, 2)", 5.0, 2.0),
    ("log10(1000)", 0.0, 3.0),
    ("log(1)", 0.0, 0.0),
    ("exp(0)", 0.0, 1.0),
    ("sqrt(16)", 0.0, 4.0),
    ("abs(-2.5)", 0.0, 2.5),
    ("abs(m-5)", 3.0, 2.0),
    ("pow(2,10)", 0.0, 1024.0),
    ("pow(m, 0.5)", 9.0, 3.0),
    ("pi", 0.0, math.pi),
    ("e", 0.0, math.e),
    ("log(e)", 0.0, 1.0),
    ("2*pi", 0.0, 2 * math.pi),
    ("3", 0.0, 3.0),
    ("3.5", 0.0, 3.5),
    (".5", 0.0, 0.5),
    ("3.", 0.0, 3.0),
    ("6e-13", 0.0, 6e-13),
    ("1E+3", 0.0, 1000.0),
    ("1e3*m", 2.0, 2000.0),
    (" \t( 1 +\n2 ) ", 0.0, 3.0),
    ("min(1, 2e-4*m**2)", 10.0, 0.02),
    ("min(1, 2e-4*m**2)", 1000.0, 1.0),
]


@pytest.mark.parametrize(("text", "m", "want"), TABLE)
def test_value_table(text: str, m: float, want: float) -> None:
    got = compile_expr(text)(m)
    assert type(got) is float
    assert got == pytest.approx(want, rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("d", [1.0, 3.0, 6.0])
def test_power_law(d: float) -> None:
    assert compile_expr("6e-13*m^13.7")(d) == pytest.approx(6e-13 * d**13.7, rel=1e-12)


def test_vectorised_over_arrays() -> None:
    d = np.array([1.0, 3.0, 6.0])
    np.testing.assert_allclose(compile_expr("6e-13*m^13.7")(d), 6e-13 * d**13.7, rtol=1e-12)
    np.testing.assert_array_equal(compile_expr("max(m, 2)")(np.array([0.0, 1.5, 2.0, 7.0])), [2, 2, 2, 7])


def test_shapes_and_types() -> None:
    ex = compile_expr("m*2")
    grid = np.arange(6.0).reshape(2, 3)
    out = ex(grid)
    assert out.shape == (2, 3) and out.dtype == np.float64
    np.testing.assert_array_equal(out, grid * 2)
    zero_d = ex(np.array(4.0))
    assert isinstance(zero_d, np.ndarray) and zero_d.shape == () and float(zero_d) == 8.0
    assert ex(np.array([], dtype=float)).shape == (0,)
    ints = ex(np.array([1, 2, 3]))  # int arrays are cast, so m^-1 stays legal
    assert ints.dtype == np.float64
    assert compile_expr("m^-1")(np.array([2, 4])).tolist() == [0.5, 0.25]
    assert ex(3) == 6.0 and type(ex(3)) is float
    assert ex(np.float32(1.5)) == 3.0
    assert ex([1.0, 2.0]).tolist() == [2.0, 4.0]  # a list is taken as an array


def test_constant_broadcasts_to_input_shape() -> None:
    ex = compile_expr("2*3-1")
    assert ex.constant == 5.0 and not ex.uses_m
    assert ex(7.0) == 5.0
    out = ex(np.zeros((2, 2)))
    assert out.shape == (2, 2) and (out == 5.0).all()


def test_result_is_a_new_array() -> None:
    d = np.array([1.0, 2.0])
    out = compile_expr("m")(d)
    assert out is not d
    out[0] = 99.0
    assert d.tolist() == [1.0, 2.0]


def test_attributes() -> None:
    ex = compile_expr(" 6e-13*m^13.7 ")
    assert ex.text == " 6e-13*m^13.7 "
    assert ex.uses_m and ex.constant is None
    assert isinstance(ex, Expr)
    assert compile_expr("pow(2,10)").constant == 1024.0
    assert compile_expr("0*m").uses_m  # m is there even if it cannot matter
    assert repr(ex) == "compile_expr(' 6e-13*m^13.7 ')"
    assert ex == compile_expr(" 6e-13*m^13.7 ") and hash(ex) == hash(compile_expr(" 6e-13*m^13.7 "))


def test_left_to_right_evaluation_is_kept() -> None:
    # Folding 1e16-1e16 first would give 1; left to right, 1+1e16 rounds to 1e16 and the result is 0.
    assert compile_expr("m + 1e16 - 1e16")(1.0) == 0.0
    assert compile_expr("1e16 + m - 1e16")(1.0) == 0.0
    assert compile_expr("m + (1e16 - 1e16)")(1.0) == 1.0


def test_long_chains_evaluate_in_order() -> None:
    ex = compile_expr("+".join(["m"] * 300))
    assert ex(2.0) == 600.0
    np.testing.assert_array_equal(ex(np.array([1.0, 0.5])), [300.0, 150.0])
    assert compile_expr("1" + "-1" * 400 + "+m")(0.5) == -398.5
    many = "min(" + ",".join(str(k) for k in range(50, 0, -1)) + ", m)"
    assert compile_expr(many)(np.array([0.5, 9])).tolist() == [0.5, 1.0]


def test_no_numeric_warnings() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert compile_expr("1/(m-3)")(3.0) == math.inf
        assert compile_expr("log(m)")(0.0) == -math.inf
        assert compile_expr("exp(m)")(1e4) == math.inf
        assert math.isnan(compile_expr("sqrt(m)")(-1.0))
        assert math.isnan(compile_expr("0/(m-3)")(3.0))
        assert math.isnan(compile_expr("(-8)^(1/3)")(0.0))  # numpy, not complex
        out = compile_expr("1/(m-3)")(np.array([3.0, 4.0]))
        assert out.tolist() == [math.inf, 1.0]
        assert compile_expr("1e999")(0.0) == math.inf
        assert compile_expr("1/0")(np.zeros(2)).tolist() == [math.inf, math.inf]  # folded at compile time


def test_min_max_propagate_nan() -> None:
    assert math.isnan(compile_expr("min(1, sqrt(m))")(-1.0))


# (text, exact message, column)
BAD: list[tuple[str, str, int]] = [
    ("__import__('os')", "unknown name '__import__' at column 1 "
     "(allowed: m, pi, e, exp, log, log10, sqrt, pow, min, max, abs)", 1),
    ("m; import os", "unexpected character ';' at column 2", 2),
    ("os.system('x')", "unknown name 'os' at column 1", 1),
    ("lambda: 1", "unknown name 'lambda' at column 1", 1),
    ("m m", "unexpected 'm' at column 3 (expected an operator or end of expression)", 3),
    ("2 m", "unexpected 'm' at column 3", 3),
    ("2 +", "unexpected end of expression at column 4", 4),
    ("2**", "unexpected end of expression at column 4", 4),
    ("(", "unexpected end of expression at column 2", 2),
    ("(2", "unclosed '(' at column 1", 1),
    (")", "unbalanced ')' at column 1", 1),
    ("m)", "unbalanced ')' at column 2", 2),
    ("(m))", "unbalanced ')' at column 4", 4),
    ("()", "unexpected ')' at column 2", 2),
    ("pow(1)", "'pow' takes 2 arguments, got 1 at column 1", 1),
    ("3 * pow(1, 2, 3)", "'pow' takes 2 arguments, got 3 at column 5", 5),
    ("min(1)", "'min' takes at least 2 arguments, got 1 at column 1", 1),
    ("exp()", "'exp' takes 1 argument, got 0 at column 1", 1),
    ("log(2, 10)", "'log' takes 1 argument, got 2 at column 1", 1),
    ("foo(2)", "unknown name 'foo' at column 1", 1),
    ("M", "unknown name 'M' at column 1", 1),
    ("Exp(1)", "unknown name 'Exp' at column 1", 1),
    ("x", "unknown name 'x' at column 1", 1),
    ("m[0]", "unexpected character '[' at column 2", 2),
    ('"m"', "unexpected character '\"' at column 1", 1),
    ("0.1*'m'", "unexpected character \"'\" at column 5", 5),
    ("1e", "malformed number '1e' at column 1", 1),
    ("2*1e+", "malformed number '1e+' at column 3", 3),
    ("1.2.3", "malformed number '1.2.3' at column 1", 1),
    ("3m", "malformed number '3m' at column 1", 1),
    ("0x10", "malformed number '0x10' at column 1", 1),
    ("1_000", "malformed number '1_000' at column 1", 1),
    (".", "malformed number '.' at column 1", 1),
    ("exp", "function 'exp' without '(...)' at column 1", 1),
    ("m(2)", "unexpected '(' after 'm' at column 2 ('m' is not a function)", 2),
    ("min(1 2)", "unexpected '2' at column 7 (expected an operator, ',' or ')')", 7),
    ("min(1,,2)", "unexpected ',' at column 7", 7),
    ("2 ** ** 3", "unexpected '**' at column 6", 6),
    ("2 ^ * 3", "unexpected '*' at column 5", 5),
    ("1, 2", "unexpected ',' at column 2", 2),
    ("m % 2", "unexpected character '%' at column 3", 3),
    ("m == 1", "unexpected character '=' at column 3", 3),
    ("m\n+\n@", "unexpected character '@' at column 5", 5),
    ("m\x00", "unexpected character '\\x00' at column 2", 2),
    ("2·m", "unexpected character '·' at column 2", 2),
    ("٣", "unexpected character '٣' at column 1", 1),  # a Unicode digit that float() would accept
    ("", "empty expression", 1),
    ("   \n\t", "empty expression", 1),
    ("m+" * 1000 + "m",
     "expression too long: 2001 characters, limit 1000 (excess starts at column 1001)", 1001),
    ("(" * 500 + "m" + ")" * 499, f"'(' nests deeper than {MAX_DEPTH} levels at column 101", 101),
    ("(" * 101 + "m" + ")" * 101, "'(' nests deeper than 100 levels at column 101", 101),
    ("exp(" * 101 + "m" + ")" * 101, "'(' nests deeper than 100 levels at column 404", 404),
    ("2^" * 101 + "2", "'^' nests deeper than 100 levels at column 202", 202),
]


@pytest.mark.parametrize(("text", "message", "column"), BAD, ids=[repr(b[0][:20]) for b in BAD])
def test_bad_expressions(text: str, message: str, column: int) -> None:
    with pytest.raises(ExprError) as info:
        compile_expr(text)
    err = info.value
    assert str(err).startswith(message)
    assert err.column == column
    assert "\n" not in str(err) and "Traceback" not in str(err)
    assert isinstance(err, ValueError)


def test_limits_are_inclusive() -> None:
    assert compile_expr("(" * MAX_DEPTH + "m" + ")" * MAX_DEPTH)(2.0) == 2.0
    assert compile_expr("2^" * MAX_DEPTH + "1")(1.0) == math.inf
    assert compile_expr("exp(" * MAX_DEPTH + "m" + ")" * MAX_DEPTH)(-1e9) == math.inf
    assert compile_expr("-" * 900 + "m")(2.0) == 2.0  # signs are not nesting
    text = "m" + "+0" * 499 + " "
    assert len(text) == MAX_LENGTH
    assert compile_expr(text)(1.0) == 1.0
    with pytest.raises(ExprError, match="column 1001"):
        compile_expr(text + " ")


def test_non_str_is_a_type_error() -> None:
    with pytest.raises(TypeError):
        compile_expr(3)  # type: ignore[arg-type]


def test_error_pickles_with_its_column() -> None:
    with pytest.raises(ExprError) as info:
        compile_expr("2 +* 3")
    back = pickle.loads(pickle.dumps(info.value))
    assert isinstance(back, ExprError) and back.column == info.value.column == 4
    assert str(back) == str(info.value)


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet=st.sampled_from(list("0123456789.eE+-*/^(), m\tpixlogsqrtnaxbw_[]'\";")), max_size=40))
def test_fuzz_only_expr_errors(text: str) -> None:
    """Any text either compiles or raises ExprError; compiled ones evaluate without raising."""
    try:
        ex = compile_expr(text)
    except ExprError as err:
        assert 1 <= err.column <= len(text) + 1
        return
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert isinstance(ex(1.5), float)
        assert ex(np.array([0.0, 2.0])).shape == (2,)


@settings(max_examples=100, deadline=None)
@given(st.text(max_size=30))
def test_fuzz_any_unicode(text: str) -> None:
    with contextlib.suppress(ExprError):  # anything else propagates and fails the test
        compile_expr(text)


# ------------------------------------------------------------------ random trees, checked by a tree walk

Tree = Any
_FUNCS1 = {"exp": np.exp, "log": np.log, "log10": np.log10, "sqrt": np.sqrt, "abs": np.abs}
_FUNCSN = {"pow": np.power, "min": np.minimum, "max": np.maximum}
_BIN = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide, "^": np.power, "**": np.power}

_leaf = st.one_of(
    st.floats(min_value=-10, max_value=10, allow_nan=False, allow_infinity=False),
    st.integers(min_value=0, max_value=9).map(float),
    st.sampled_from(["m", "m", "pi", "e"]),
)


def _extend(children: st.SearchStrategy[Tree]) -> st.SearchStrategy[Tree]:
    return st.one_of(
        st.tuples(st.sampled_from(list(_BIN)), children, children),
        st.tuples(st.just("neg"), children),
        st.tuples(st.sampled_from(list(_FUNCS1)), children),
        st.tuples(st.just("pow"), children, children),
        st.tuples(st.sampled_from(["min", "max"]), children, children, st.lists(children, max_size=2)),
    )


trees = st.recursive(_leaf, _extend, max_leaves=12)


def walk(t: Tree, m: Any) -> Any:
    """The test's own evaluation: the same numpy float64 operations, applied to the tree directly."""
    if isinstance(t, float):
        return np.float64(t)
    if t == "m":
        return m
    if t == "pi":
        return np.float64(math.pi)
    if t == "e":
        return np.float64(math.e)
    op = t[0]
    if op == "neg":
        return np.negative(walk(t[1], m))
    if op in _FUNCS1:
        return _FUNCS1[op](walk(t[1], m))
    if op == "pow":
        return np.power(walk(t[1], m), walk(t[2], m))
    if op in ("min", "max"):
        acc = walk(t[1], m)
        for arg in [t[2], *t[3]]:
            acc = _FUNCSN[op](acc, walk(arg, m))
        return acc
    return _BIN[op](walk(t[1], m), walk(t[2], m))


# Precedence levels for rendering with as few parentheses as the grammar allows.
_SUM, _PROD, _UNARY, _POW, _ATOM = 1, 2, 3, 4, 5


def render(t: Tree) -> tuple[str, int]:
    """Tree -> (text, precedence of its top operator)."""
    if isinstance(t, float):
        if math.copysign(1.0, t) < 0:
            return f"-{-t!r}", _UNARY
        return repr(t), _ATOM
    if isinstance(t, str):
        return t, _ATOM
    op = t[0]
    if op == "neg":
        return "-" + _wrap(t[1], _UNARY), _UNARY
    if op in _FUNCS1:
        return f"{op}({render(t[1])[0]})", _ATOM
    if op == "pow":
        return f"pow({render(t[1])[0]}, {render(t[2])[0]})", _ATOM
    if op in ("min", "max"):
        return f"{op}({', '.join(render(a)[0] for a in [t[1], t[2], *t[3]])})", _ATOM
    if op in ("^", "**"):  # right-associative, tighter than unary minus on its left only
        return f"{_wrap(t[1], _ATOM)} {op} {_wrap(t[2], _UNARY)}", _POW
    level = _SUM if op in "+-" else _PROD
    return f"{_wrap(t[1], level)} {op} {_wrap(t[2], level + 1)}", level


def _wrap(t: Tree, at_least: int) -> str:
    text, level = render(t)
    return text if level >= at_least else f"({text})"


def _same(got: Any, want: Any) -> None:
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=0, equal_nan=True)


@settings(max_examples=400, deadline=None)
@given(trees, st.floats(min_value=0, max_value=1000), st.lists(st.floats(min_value=0, max_value=1000),
                                                              min_size=1, max_size=5))
def test_random_trees_match_tree_walk(tree: Tree, d: float, ds: list[float]) -> None:
    text = render(tree)[0]
    ex = compile_expr(text)
    with np.errstate(all="ignore"):
        want_scalar = walk(tree, np.float64(d))
        arr = np.array(ds)
        want_array = np.broadcast_to(walk(tree, arr), arr.shape)
    _same(ex(d), want_scalar)
    _same(ex(arr), want_array)


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=1e-20, max_value=1e3), st.floats(min_value=0, max_value=20),
       st.lists(st.floats(min_value=0, max_value=1e4), min_size=1, max_size=8), st.sampled_from(["^", "**"]))
def test_power_law_random(a: float, b: float, ds: list[float], op: str) -> None:
    d = np.array(ds)
    with np.errstate(over="ignore"):
        want = a * d**b
    _same(compile_expr(f"{a!r}*m{op}{b!r}")(d), want)
