"""Safe evaluation of the growth curve, an arithmetic expression in ``x``.

The curve comes from a config file a user wrote: it is parsed with :mod:`ast` and
evaluated by walking a whitelist of node types. Nothing is ever ``eval``'d.
"""

import ast
import operator

import numpy as np

_BINARY = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
}
_UNARY = {ast.UAdd: operator.pos, ast.USub: operator.neg}
_FUNCTIONS = {
    "abs": np.abs,
    "sqrt": np.sqrt,
    "exp": np.exp,
    "log": np.log,
    "sin": np.sin,
    "cos": np.cos,
    "tanh": np.tanh,
    "cosh": np.cosh,
}
_CONSTANTS = {"pi": np.pi, "e": np.e}
VARIABLE = "x"


def parse_curve(text: str) -> ast.Expression:
    """Parse ``text`` and check that it only uses numbers, ``x``, + - * / **, and
    the functions in ``_FUNCTIONS``. Raises ``ValueError`` with a short reason."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError("empty expression")
    if len(text) > 500:
        raise ValueError("expression longer than 500 characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ValueError(f"not an expression of x ({exc.msg})") from None
    for node in ast.walk(tree):
        if isinstance(node, (ast.Expression, ast.Load)) or type(node) in _BINARY or type(node) in _UNARY:
            continue
        if isinstance(node, (ast.BinOp, ast.UnaryOp)):
            op = node.op
            if type(op) not in _BINARY and type(op) not in _UNARY:
                raise ValueError(f"operator {type(op).__name__} is not allowed")
            continue
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
                raise ValueError(f"constant {node.value!r} is not a number")
            continue
        if isinstance(node, ast.Name):
            if node.id != VARIABLE and node.id not in _CONSTANTS and node.id not in _FUNCTIONS:
                raise ValueError(f"unknown name {node.id!r} (the variable is x)")
            continue
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS:
                raise ValueError("only the functions " + ", ".join(sorted(_FUNCTIONS)) + " may be called")
            if len(node.args) != 1 or node.keywords:
                raise ValueError(f"{node.func.id}() takes one argument")
            continue
        raise ValueError(f"{type(node).__name__} is not allowed in a growth curve")
    return tree


def _evaluate(node, x):
    if isinstance(node, ast.Expression):
        return _evaluate(node.body, x)
    if isinstance(node, ast.Constant):
        return float(node.value)
    if isinstance(node, ast.Name):
        if node.id == VARIABLE:
            return x
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        raise ValueError(f"{node.id}() must be called")
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_evaluate(node.left, x), _evaluate(node.right, x))
    if isinstance(node, ast.UnaryOp):
        return _UNARY[type(node.op)](_evaluate(node.operand, x))
    if isinstance(node, ast.Call):
        return _FUNCTIONS[node.func.id](_evaluate(node.args[0], x))
    raise ValueError(f"{type(node).__name__} is not allowed")  # unreachable after parse_curve


def evaluate_curve(text: str, x: np.ndarray) -> np.ndarray:
    """Evaluate the growth curve ``text`` at the cross-section coordinates ``x``.

    Returns an array shaped like ``x``. Raises ``ValueError`` if the text is not a valid
    expression or gives a non-finite value somewhere on ``x``.
    """
    tree = parse_curve(text)
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(all="ignore"):
        y = np.broadcast_to(np.asarray(_evaluate(tree, x), dtype=np.float64), x.shape).copy()
    if not np.all(np.isfinite(y)):
        bad = x[~np.isfinite(y)]
        raise ValueError(f"not finite at x = {bad.flat[0]:.3g}")
    return y


def check_curve(text: str) -> None:
    """Raise ``ValueError`` unless ``text`` is a curve that is finite on [-1, 1] and above
    -1 there (alpha <= -1 would make a rest length zero or negative, Eq. 6)."""
    x = np.linspace(-1.0, 1.0, 201)
    y = evaluate_curve(text, x)
    if np.any(y <= -1.0):
        at = x[np.argmin(y)]
        raise ValueError(f"{y.min():.3g} at x = {at:.3g}: a growth ratio <= -1 makes a rest "
                         "length zero or negative")
