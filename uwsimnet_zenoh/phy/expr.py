"""A safe parser for the error-rate expressions of scene files, e.g. ``6e-13*m^13.7``.

Scene files are user text: they are tokenised and parsed by hand here and never reach ``eval``.  The
result is a small tree of closures over numpy ufuncs, so one compiled expression evaluates a whole array
of distances at once, and constant sub-trees are folded at compile time.

Grammar (whitespace is allowed between any two tokens; names are case-sensitive)::

    expr   := term (('+' | '-') term)*
    term   := factor (('*' | '/') factor)*
    factor := ('+' | '-')* atom (('^' | '**') factor)?
    atom   := NUMBER | 'm' | 'pi' | 'e' | FUNC '(' expr (',' expr)* ')' | '(' expr ')'

so ``^`` and ``**`` are the same operator, right-associative and binding tighter than unary minus
(``-2^2 == -4``, ``2^3^2 == 512``, ``2^-1 == 0.5``), as in Python.  A letter ``e``/``E`` right after the
digits of a number always starts its exponent: ``2e`` is a malformed number, not ``2*e``.

Semantics are numpy's float64: division by zero gives ±inf or nan, ``log(0)`` gives -inf, a negative
base to a fractional power gives nan, ``min``/``max`` propagate nan, ``1e999`` is inf.  These produce no
warnings (``np.errstate(all="ignore")``); sanitising is the caller's job (see ``phy.error``).

Evaluation cost, microseconds per ``expr(x)`` call (best of 9 x 100k ``timeit`` runs; CPython 3.11.7,
numpy 2.4.6, a shared 2-core container, so +-30%)::

    expression           x = float   x = ndarray[1]   x = ndarray[256]
    6e-13*m^13.7            2.7           2.5              3.3
    0.01*m                  2.1           1.9              2.8
    1e-5*exp(0.3*m)         3.1           2.7              3.1
    min(1, 2e-4*m**2)       3.3           3.2              3.8
    0.1  (constant)         0.2           1.1              1.2

About 0.9 us of each is entering and leaving ``np.errstate``, ~0.5 us each numpy call on a small array;
``Expr.unguarded`` skips the former for callers that already hold the errstate (``phy.error`` does).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any, overload

import numpy as np

from ..errors import UwsimnetError

__all__ = ["ALLOWED_NAMES", "MAX_DEPTH", "MAX_LENGTH", "Expr", "ExprError", "compile_expr"]

MAX_LENGTH = 1000
"""Longest accepted expression, in characters: a bound on parse time and tree size."""

MAX_DEPTH = 100
"""Deepest accepted nesting of parentheses, call arguments and exponents (``2^2^2`` is depth 2)."""

_Fn = Callable[[Any], Any]
_Op2 = Callable[[Any, Any], Any]

_FUNCS1: dict[str, Callable[[Any], Any]] = {
    "exp": np.exp, "log": np.log, "log10": np.log10, "sqrt": np.sqrt, "abs": np.abs,
}
_FUNCSN: dict[str, tuple[_Op2, int, int | None]] = {
    # name: (binary ufunc folded left to right, min args, max args)
    "pow": (np.power, 2, 2), "min": (np.minimum, 2, None), "max": (np.maximum, 2, None),
}
_CONSTS: dict[str, float] = {"pi": math.pi, "e": math.e}
ALLOWED_NAMES: tuple[str, ...] = ("m", "pi", "e", "exp", "log", "log10", "sqrt", "pow", "min", "max", "abs")

_BINOPS: dict[str, _Op2] = {"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide}
_SPACE = " \t\r\n\f\v"
_OPCHARS = "+-*/^(),"
_NUMBER = re.compile(r"(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_NUMBER_TAIL = re.compile(r"[A-Za-z0-9_.]*(?:(?<=[eE])[+-][A-Za-z0-9_.]*)?")


class ExprError(UwsimnetError, ValueError):
    """A rejected expression.  One line, naming the offending token and its 1-based `column`.

    A ValueError so that pydantic validators and CLI front ends report it like any other bad value.
    """

    def __init__(self, message: str, column: int) -> None:
        super().__init__(message)
        self.message = message
        self.column = column

    def __reduce__(self) -> tuple[type[ExprError], tuple[str, int]]:
        # Default exception pickling would call ExprError(message) and lose `column`.
        return (ExprError, (self.message, self.column))


def _show(text: str) -> str:
    """A token as quoted in a message: repr() keeps quotes and control characters on one line."""
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _err(what: str, column: int, hint: str = "") -> ExprError:
    return ExprError(f"{what} at column {column}" + (f" ({hint})" if hint else ""), column)


# ---------------------------------------------------------------------------------------------- tokens

_NUM, _ID, _OP, _END = "number", "name", "op", "end"


class _Tok:
    __slots__ = ("kind", "text", "col", "value")

    def __init__(self, kind: str, text: str, col: int, value: float = 0.0) -> None:
        self.kind = kind
        self.text = text
        self.col = col
        self.value = value


def _tokenize(text: str) -> list[_Tok]:
    toks: list[_Tok] = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in _SPACE:
            i += 1
        elif c.isascii() and (c.isdigit() or c == "."):
            mt = _NUMBER.match(text, i)
            end = mt.end() if mt else i
            tail = _NUMBER_TAIL.match(text, end)
            assert tail is not None  # the pattern also matches the empty string
            if mt is None or tail.end() > end:
                raise _err(f"malformed number {_show(text[i:tail.end()])}", i + 1)
            # float() only ever sees [0-9.eE+-] here, validated by _NUMBER.
            toks.append(_Tok(_NUM, mt.group(), i + 1, float(mt.group())))
            i = end
        elif c.isascii() and (c.isalpha() or c == "_"):
            mt = _NAME.match(text, i)
            assert mt is not None
            name = mt.group()
            if name not in ALLOWED_NAMES:
                raise _err(f"unknown name {_show(name)}", i + 1, "allowed: " + ", ".join(ALLOWED_NAMES))
            toks.append(_Tok(_ID, name, i + 1))
            i = mt.end()
        elif c == "*" and text.startswith("**", i):
            toks.append(_Tok(_OP, "**", i + 1))
            i += 2
        elif c in _OPCHARS:
            toks.append(_Tok(_OP, c, i + 1))
            i += 1
        else:
            raise _err(f"unexpected character {c!r}", i + 1)
    toks.append(_Tok(_END, "", n + 1))
    return toks


# ------------------------------------------------------------------------------------ compiled nodes

class _Node:
    """A compiled sub-tree: a folded constant, the variable itself, or a closure of the variable.

    Keeping the three apart lets parents build specialised closures (``c * f(m)``, ``np.exp`` applied
    directly to ``m``) instead of calling one Python function per leaf.
    """

    __slots__ = ("value", "fn", "is_var")

    def __init__(self, value: np.float64 | None = None, fn: _Fn | None = None, is_var: bool = False) -> None:
        self.value = value
        self.fn = fn
        self.is_var = is_var

    def as_fn(self) -> _Fn:
        if self.fn is not None:
            return self.fn
        if self.is_var:
            return _identity
        c = self.value
        return lambda m: c


def _identity(m: Any) -> Any:
    return m


_VAR = _Node(is_var=True)


def _const(v: Any) -> _Node:
    return _Node(value=np.float64(v))


def _apply1(f: Callable[[Any], Any], a: _Node) -> _Node:
    if a.value is not None:
        return _const(f(a.value))
    if a.is_var:
        return _Node(fn=f)
    g = a.fn
    return _Node(fn=lambda m: f(g(m)))


def _apply2(op: _Op2, a: _Node, b: _Node) -> _Node:
    ca, cb = a.value, b.value
    if ca is not None and cb is not None:
        return _const(op(ca, cb))
    if cb is not None:
        if a.is_var:
            return _Node(fn=lambda m: op(m, cb))
        fa = a.fn
        return _Node(fn=lambda m: op(fa(m), cb))
    if ca is not None:
        if b.is_var:
            return _Node(fn=lambda m: op(ca, m))
        fb = b.fn
        return _Node(fn=lambda m: op(ca, fb(m)))
    fa, fb = a.as_fn(), b.as_fn()
    return _Node(fn=lambda m: op(fa(m), fb(m)))


def _chain(first: _Node, rest: list[tuple[_Op2, _Node]]) -> _Node:
    """Left fold of ``first op1 x1 op2 x2 ...``, in source order.

    Only a constant *prefix* is folded: reordering (``m+1+2`` -> ``m+3``) would change rounding and
    inf/nan outcomes.  Long chains run in one loop so evaluation depth does not grow with their length.
    """
    i = 0
    while i < len(rest) and first.value is not None and rest[i][1].value is not None:
        first = _const(rest[i][0](first.value, rest[i][1].value))
        i += 1
    rest = rest[i:]
    if len(rest) <= 2:
        for op, x in rest:
            first = _apply2(op, first, x)
        return first
    f0 = first.as_fn()
    steps = tuple((op, x.value, None if x.value is not None else x.as_fn()) for op, x in rest)

    def fold(m: Any) -> Any:
        acc = f0(m)
        for op, c, g in steps:
            acc = op(acc, c if g is None else g(m))
        return acc

    return _Node(fn=fold)


# ------------------------------------------------------------------------------------------- parser

class _Parser:
    """Recursive descent; two Python frames per nesting level, so MAX_DEPTH keeps far from the
    interpreter's recursion limit."""

    def __init__(self, toks: list[_Tok]) -> None:
        self.toks = toks
        self.i = 0
        self.depth = 0
        self.parens = 0
        self.uses_m = False

    def parse(self) -> _Node:
        node = self.expr()
        t = self.toks[self.i]
        if t.kind != _END:
            if t.text == ")":
                raise _err("unbalanced ')'", t.col)
            raise _err(f"unexpected {_show(t.text)}", t.col, "expected an operator or end of expression")
        return node

    def _enter(self, t: _Tok) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise _err(f"{_show(t.text)} nests deeper than {MAX_DEPTH} levels", t.col)

    def expr(self) -> _Node:
        toks = self.toks
        sum_first: _Node | None = None
        sum_rest: list[tuple[_Op2, _Node]] = []
        sum_op: _Op2 | None = None
        prod_first = self.factor()
        prod_rest: list[tuple[_Op2, _Node]] = []
        while True:
            t = toks[self.i]
            if t.kind != _OP or t.text not in _BINOPS:
                break
            self.i += 1
            if t.text in "*/":
                prod_rest.append((_BINOPS[t.text], self.factor()))
                continue
            term = _chain(prod_first, prod_rest)
            if sum_op is None:
                sum_first = term
            else:
                sum_rest.append((sum_op, term))
            sum_op = _BINOPS[t.text]
            prod_first, prod_rest = self.factor(), []
        term = _chain(prod_first, prod_rest)
        if sum_op is None:
            return term
        assert sum_first is not None
        sum_rest.append((sum_op, term))
        return _chain(sum_first, sum_rest)

    def factor(self) -> _Node:
        toks = self.toks
        negate = False
        t = toks[self.i]
        while t.kind == _OP and t.text in "+-":
            negate ^= t.text == "-"
            self.i += 1
            t = toks[self.i]
        node = self.atom()
        t = toks[self.i]
        if t.kind == _OP and t.text in ("^", "**"):
            self.i += 1
            self._enter(t)
            node = _apply2(np.power, node, self.factor())
            self.depth -= 1
        # -(-x) == x exactly, so a run of signs costs at most one negation.
        return _apply1(np.negative, node) if negate else node

    def atom(self) -> _Node:
        toks = self.toks
        t = toks[self.i]
        self.i += 1
        if t.kind == _NUM:
            return _const(t.value)
        if t.kind == _ID:
            nxt = toks[self.i]
            is_call = nxt.kind == _OP and nxt.text == "("
            if t.text in _FUNCS1 or t.text in _FUNCSN:
                if not is_call:
                    raise _err(f"function {_show(t.text)} without '(...)'", t.col, f"write {t.text}(...)")
                return self.call(t)
            if is_call:
                raise _err(f"unexpected '(' after {_show(t.text)}", nxt.col, f"{t.text!r} is not a function")
            if t.text == "m":
                self.uses_m = True
                return _VAR
            return _const(_CONSTS[t.text])
        if t.kind == _OP and t.text == "(":
            self._enter(t)
            self.parens += 1
            node = self.expr()
            self._close(t, in_call=False)
            self.parens -= 1
            self.depth -= 1
            return node
        if t.kind == _END:
            raise _err("unexpected end of expression", t.col)
        if t.text == ")" and not self.parens:
            raise _err("unbalanced ')'", t.col)
        raise _err(f"unexpected {_show(t.text)}", t.col, "expected a number, a name or '('")

    def call(self, name: _Tok) -> _Node:
        opening = self.toks[self.i]
        self.i += 1
        self._enter(opening)
        self.parens += 1
        args: list[_Node] = []
        if not (self.toks[self.i].kind == _OP and self.toks[self.i].text == ")"):
            args.append(self.expr())
            while self.toks[self.i].kind == _OP and self.toks[self.i].text == ",":
                self.i += 1
                args.append(self.expr())
        self._close(opening, in_call=True)
        self.parens -= 1
        self.depth -= 1
        fname = name.text
        if fname in _FUNCS1:
            if len(args) != 1:
                raise _err(f"{fname!r} takes 1 argument, got {len(args)}", name.col)
            return _apply1(_FUNCS1[fname], args[0])
        op, lo, hi = _FUNCSN[fname]
        if len(args) < lo or (hi is not None and len(args) > hi):
            need = f"{lo}" if hi == lo else f"at least {lo}"
            raise _err(f"{fname!r} takes {need} arguments, got {len(args)}", name.col)
        return _chain(args[0], [(op, a) for a in args[1:]])

    def _close(self, opening: _Tok, in_call: bool) -> None:
        t = self.toks[self.i]
        if t.kind == _OP and t.text == ")":
            self.i += 1
            return
        if t.kind == _END:
            raise _err("unclosed '('", opening.col, f"the expression ends at column {t.col}")
        raise _err(f"unexpected {_show(t.text)}", t.col,
                   "expected an operator, ',' or ')'" if in_call else "expected an operator or ')'")


# ---------------------------------------------------------------------------------------- public API

class Expr:
    """A compiled expression of the distance ``m``: call it with a float or an ndarray of distances.

    A float (or numpy scalar) gives a float; an array (of any shape, cast to float64) gives a new
    float64 array of the same shape.  Non-finite results are returned as they are, without warnings.
    """

    __slots__ = ("text", "uses_m", "constant", "_fn")

    text: str
    """The source text, unchanged."""
    uses_m: bool
    """Whether the value depends on ``m`` at all."""
    constant: float | None
    """The folded value when ``uses_m`` is false (lets callers short-circuit), else None."""

    def __init__(self, text: str, node: _Node, uses_m: bool) -> None:
        self.text = text
        self.uses_m = uses_m
        self.constant = None if node.value is None else float(node.value)
        # np.positive copies: the bare `m` must not hand the caller's own array back to it.
        self._fn: _Fn = np.positive if node.is_var else node.as_fn()

    @overload
    def __call__(self, m: float) -> float: ...
    @overload
    def __call__(self, m: np.ndarray) -> np.ndarray: ...

    def __call__(self, m: float | np.ndarray) -> float | np.ndarray:
        if isinstance(m, np.ndarray):
            x = m if m.dtype == np.float64 else m.astype(np.float64)
            if self.constant is not None:
                return np.full(x.shape, self.constant)
            with np.errstate(all="ignore"):
                r = self._fn(x)
            # A 0-d input makes the ufuncs return numpy scalars; keep the array-in, array-out contract.
            return r if x.ndim else np.asarray(r, dtype=np.float64)
        if self.constant is not None:
            return self.constant
        if isinstance(m, (float, int, np.number)):
            with np.errstate(all="ignore"):
                return float(self._fn(np.float64(m)))
        return self(np.asarray(m, dtype=np.float64))

    def unguarded(self, x: np.ndarray) -> np.ndarray:
        """Evaluate a float64 array with ``ndim >= 1`` of a non-constant expression, raw.

        No errstate, no casting, no shape fix-up: for callers that already hold
        ``np.errstate(all="ignore")`` around a larger computation (phy.error saves ~1 us per frame).
        """
        return self._fn(x)

    def __repr__(self) -> str:
        return f"compile_expr({self.text!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Expr) and other.text == self.text

    def __hash__(self) -> int:
        return hash(self.text)


_COMPILED: dict[str, Expr] = {}
"""Expressions compiled so far, by text (an Expr is immutable: a scene of N devices with the same error
rate compiles it once, not twice per device; bounded, see compile_expr)."""


def compile_expr(text: str) -> Expr:
    """Parse `text` into an `Expr`, or raise `ExprError` naming the first offending token.

    Every failure (bad character, unknown name, syntax, arity, length over MAX_LENGTH, nesting over
    MAX_DEPTH) is an ExprError; nothing in `text` is ever executed.
    """
    if not isinstance(text, str):
        raise TypeError(f"expression must be a str, not {type(text).__name__}")
    hit = _COMPILED.get(text)
    if hit is not None:
        return hit
    expr = _compile(text)
    if len(_COMPILED) >= 4096:
        _COMPILED.clear()
    _COMPILED[text] = expr
    return expr


def _compile(text: str) -> Expr:
    if len(text) > MAX_LENGTH:
        raise ExprError(f"expression too long: {len(text)} characters, limit {MAX_LENGTH}"
                        f" (excess starts at column {MAX_LENGTH + 1})", MAX_LENGTH + 1)
    if not text.strip(_SPACE):
        raise ExprError("empty expression", 1)
    parser = _Parser(_tokenize(text))
    with np.errstate(all="ignore"):
        try:
            node = parser.parse()
        except RecursionError:  # pragma: no cover - MAX_DEPTH should make this unreachable
            raise ExprError("expression nested too deeply", 1) from None
    return Expr(text, node, parser.uses_m)
