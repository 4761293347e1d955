"""Command-line flags generated from a config dataclass, so that a flag is always its field's name.

``add_config_arguments(parser, PipelineConfig)`` adds ``--eval-scenes`` for the field ``eval_scenes``;
booleans as ``--render/--no-render``; tuples as comma-separated values (``--tasks hammer,sweep``); a
dict as JSON; a nested dataclass field's fields under its name (``--ln-timesteps`` for ``ln.timesteps``).
The help is the field's docstring. ``config_overrides(args, PipelineConfig)`` returns the flags given, as
the nested overrides ``prl.config.make_config`` and the Prefect flows take (``{"ln": {"timesteps": 64}}``).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import itertools
import json
import textwrap
import types
import typing
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of the dataclass ``cls`` (``{}`` when its source cannot be read)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError):
        return {}
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for stmt, nxt in itertools.pairwise(body):
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) and isinstance(nxt, ast.Expr) \
                and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
            docs[stmt.target.id] = " ".join(nxt.value.value.split())
    return docs


def _unwrap_optional(hint: Any) -> Any:
    """``X`` of ``X | None``; ``hint`` otherwise."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return hint


def _scalar(tp: Any) -> Callable[[str], Any]:
    """A converter of one command-line value to ``tp`` (paths stay strings: the config makes them paths)."""
    if tp is Path or tp is str:
        return str
    if tp in (int, float):
        def convert(text: str) -> Any:
            try:
                return tp(text)
            except ValueError:
                raise argparse.ArgumentTypeError(f"expected {'an integer' if tp is int else 'a number'}, "
                                                 f"got {text!r}") from None
        return convert
    raise TypeError(f"no command-line form for the type {tp!r}")


def _converter(hint: Any) -> tuple[Callable[[str], Any], str]:
    """The argparse ``type`` of a field's type hint, and its metavar."""
    tp = _unwrap_optional(hint)
    origin = typing.get_origin(tp)
    if origin in (tuple, list):
        item = _scalar(typing.get_args(tp)[0])
        name = getattr(typing.get_args(tp)[0], "__name__", "value").upper()

        def csv(text: str) -> list[Any]:
            try:
                return [item(v.strip()) for v in text.split(",") if v.strip()]
            except argparse.ArgumentTypeError as exc:
                raise argparse.ArgumentTypeError(f"expected comma-separated values: {exc}") from None
        return csv, f"{name},..."
    if tp is dict or origin is dict:
        def as_json(text: str) -> dict[str, Any]:
            try:
                value = json.loads(text)
            except json.JSONDecodeError as exc:
                raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r} ({exc})") from None
            if not isinstance(value, dict):
                raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
            return value
        return as_json, "JSON"
    return _scalar(tp), "PATH" if tp is Path else getattr(tp, "__name__", "value").upper()


def add_config_arguments(parser: argparse.ArgumentParser, cls: type, prefix: str = "",
                         exclude: Collection[str] = ()) -> None:
    """One flag per field of the dataclass ``cls`` (``--`` + its dotted name with ``_`` and ``.`` as ``-``), except
    the dotted names in ``exclude``; every flag's default is None (not given)."""
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        if name in exclude:
            continue
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint):
            add_config_arguments(parser, hint, f"{name}.", exclude)
            continue
        flag = "--" + name.replace("_", "-").replace(".", "-")
        help_text = docs.get(f.name, f"{cls.__name__}.{f.name}").replace("%", "%%")
        if _unwrap_optional(hint) is bool:
            parser.add_argument(flag, dest=name, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        else:
            convert, metavar = _converter(hint)
            parser.add_argument(flag, dest=name, type=convert, default=None, metavar=metavar, help=help_text)


def config_overrides(args: argparse.Namespace, cls: type, prefix: str = "",
                     exclude: Collection[str] = ()) -> dict[str, Any]:
    """The fields of ``cls`` given on the command line (``add_config_arguments``' flags that are not None; not the
    dotted names in ``exclude``), nested like the config: ``{"eval_scenes": 3, "ln": {"timesteps": 64}}``."""
    given = vars(args)
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        name = prefix + f.name
        if name in exclude:
            continue
        if dataclasses.is_dataclass(hints[f.name]):
            nested = config_overrides(args, hints[f.name], f"{name}.", exclude)
            if nested:
                out[f.name] = nested
        elif given.get(name) is not None:
            out[f.name] = given[name]
    return out
