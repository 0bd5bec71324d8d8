"""The arithmetic a study file may write for a value: numbers, names, + - * / and ( ), e.g.
``advisor_episodes = "0.5 * episodes"`` or ``eps_decay = "eps_start / advisor_episodes"``
(``spec.resolve`` orders and evaluates them)."""

from __future__ import annotations

import ast
import operator
from collections.abc import Mapping

_OPERATORS = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
}


def names_in(text: str) -> set[str]:
    """The names an expression reads (a syntax error or another construct: ValueError)."""
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError:
        raise ValueError(f"{text!r} is not an expression") from None
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            out.add(node.id)
        elif not isinstance(
            node, (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Constant, ast.Load, *_OPERATORS)
        ):
            raise ValueError(f"{text!r}: only numbers, names, + - * / and ( ) are allowed")
    return out


def evaluate(text: str, values: Mapping[str, float]) -> float:
    """The value of an expression given its names' values."""

    def walk(node):
        if isinstance(node, ast.Expression):
            return walk(node.body)
        if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
            return float(node.value)
        if isinstance(node, ast.Name):
            return float(values[node.id])
        if isinstance(node, ast.UnaryOp):
            return _OPERATORS[type(node.op)](walk(node.operand))
        if isinstance(node, ast.BinOp):
            left, right = walk(node.left), walk(node.right)
            if isinstance(node.op, ast.Div) and right == 0:
                raise ValueError(f"{text!r} divides by zero")
            return _OPERATORS[type(node.op)](left, right)
        raise ValueError(f"{text!r}: only numbers, names, + - * / and ( ) are allowed")

    names_in(text)
    return walk(ast.parse(text, mode="eval"))
