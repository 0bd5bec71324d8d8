"""Option help that reads at any terminal width: ``flowing`` prepares a tyro command.

tyro keeps every line break of a field's docstring, and rich then wraps each source line on
its own, so help written at 100 columns broke mid-sentence at 80 (and at 100, after
rewrapping). It also showed ``{None}|INT`` for an optional number, ``(default: )`` for an
empty list and ``--no-progress, --no-no-progress`` for a flag. ``flowing(obj)`` (an options
dataclass or a command function) gives tyro, per option:

* the docstring (or ``Args:`` entry) as one paragraph, its line breaks joined;
* for ``X | None``: X's metavar (``INT``, ``STR``, ``STR [STR ...]``) and no
  ``(default: None)`` (the help says what leaving it out means);
* for an empty tuple default: ``(default: none)``;
* for a ``bool``: one flag (``--no-progress`` sets True; ``--json`` likewise).

Help given explicitly (``tyro.conf.arg(help=...)``, e.g. the hyperparameter table of
``--hp``) and explicit metavars are kept as written.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import pathlib
import textwrap
import types
import typing
from typing import Annotated, Any

import tyro

_ONE_FLAG = typing.get_args(tyro.conf.FlagCreatePairsOff[bool])[1]
_NAMES = {int: "INT", float: "FLOAT", str: "STR", pathlib.Path: "PATH"}


def flowing(obj):
    """Rewrites the annotations of a tyro options dataclass or command function (module
    docstring); returns ``obj``."""
    if dataclasses.is_dataclass(obj):
        docs = _field_docstrings(obj)
        defaults = {f.name: f.default for f in dataclasses.fields(obj)}
    else:
        docs = _argument_docs(obj)
        defaults = {p.name: p.default for p in inspect.signature(obj).parameters.values()}
    hints = typing.get_type_hints(obj, include_extras=True)
    for name, default in defaults.items():
        obj.__annotations__[name] = _annotated(hints[name], docs.get(name), default)
    return obj


def _annotated(hint, doc: str | None, default: Any):
    """``hint`` with our tyro settings first, so that settings written in the source win."""
    base, *extra = typing.get_args(hint) if typing.get_origin(hint) is Annotated else (hint,)
    conf: dict[str, Any] = {}
    if doc:
        conf["help"] = " ".join(doc.split())
    inner = _optional_inner(base)
    if inner is not None:
        conf["help_behavior_hint"] = ""
        metavar = _metavar(inner)
        if metavar:
            conf["metavar"] = metavar
    elif default == () and isinstance(default, tuple):
        conf["help_behavior_hint"] = "(default: none)"
    markers = [_ONE_FLAG] if base is bool else []
    return Annotated[(base, tyro.conf.arg(**conf), *markers, *extra)]


def _optional_inner(tp):
    """X of ``X | None`` (None for other types)."""
    if typing.get_origin(tp) not in (typing.Union, types.UnionType):
        return None
    args = [a for a in typing.get_args(tp) if a is not type(None)]
    return args[0] if len(args) == 1 and len(typing.get_args(tp)) == 2 else None


def _metavar(tp) -> str | None:
    if typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis and args[0] in _NAMES:
            name = _NAMES[args[0]]
            return f"{name} [{name} ...]"
        return None
    return _NAMES.get(tp)


def _field_docstrings(cls) -> dict[str, str]:
    """{field: the string literal right below it} of a dataclass's source."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    docs = {}
    for node, after in zip(body, body[1:], strict=False):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.target.id] = after.value.value
    return docs


def _argument_docs(function) -> dict[str, str]:
    """{parameter: its ``Args:`` entry} of a function's Google-style docstring."""
    import docstring_parser

    parsed = docstring_parser.parse(inspect.getdoc(function) or "")
    return {p.arg_name: p.description for p in parsed.params if p.description}
