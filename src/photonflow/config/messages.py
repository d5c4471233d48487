"""One-line error messages from pydantic ``ValidationError``s.

``one_line_error`` takes the first error of a ``ValidationError`` and renders it as
``<dotted.field> = <value>: <rule>`` (or ``<dotted.field>: unknown field; did you mean
'<name>'?`` for a misspelt key), so that the command line can print it as is. The tag
that pydantic inserts into the location of a discriminated union (``shape.cylinder.radius``)
is dropped, giving the path as written in the file (``shape.radius``).
"""

from __future__ import annotations

import difflib
import types
import typing
from collections.abc import Sequence

from pydantic import BaseModel, ValidationError

from ..errors import ConfigError, PhotonflowError, format_value

#: Rules for pydantic's built-in error types (anything else: pydantic's own message).
_RULES = {
    "float_parsing": "must be a number",
    "float_type": "must be a number",
    "int_parsing": "must be an integer",
    "int_type": "must be an integer",
    "int_from_float": "must be an integer",
    "string_type": "must be a string",
    "bool_parsing": "must be true or false",
    "bool_type": "must be true or false",
    "dict_type": "must be a mapping (key: value pairs)",
    "model_type": "must be a mapping (key: value pairs)",
    "model_attributes_type": "must be a mapping (key: value pairs)",
    "tuple_type": "must be a list",
    "list_type": "must be a list",
}


def _models_in(annotation: object) -> list[type[BaseModel]]:
    """The pydantic models an annotation may hold (through Optional, Union, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _models_in(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [model for arg in typing.get_args(annotation) for model in _models_in(arg)]
    return []


def _tag(model: type[BaseModel]) -> str | None:
    """The ``kind`` literal of a tagged-union member, if it has one."""
    field = model.model_fields.get("kind")
    if field is None or typing.get_origin(field.annotation) is not typing.Literal:
        return None
    return typing.get_args(field.annotation)[0]


def _walk(root: type[BaseModel], loc: Sequence[int | str]) -> tuple[list[int | str], list]:
    """Drop union tags from ``loc``; return the clean location and the models found there."""
    clean: list[int | str] = []
    models: list[type[BaseModel]] = [root]
    for part in loc:
        tagged = {_tag(model): model for model in models if len(models) > 1}
        if isinstance(part, str) and part in tagged:
            models = [tagged[part]]
            continue
        clean.append(part)
        fields = models[0].model_fields if len(models) == 1 else {}
        models = _models_in(fields[part].annotation) if part in fields else []
    return clean, models


def dotted(loc: Sequence[int | str]) -> str:
    """``("detector", "shape", "radius")`` -> ``detector.shape.radius``; ints as ``[i]``."""
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text or "config"


def _unknown_field(path: str, name: str, known: Sequence[str]) -> str:
    close = difflib.get_close_matches(str(name), list(known), n=1, cutoff=0.6)
    if close:
        return f"{path}: unknown field; did you mean '{close[0]}'?"
    listed = ", ".join(known) if known else "none"
    return f"{path}: unknown field; known: {listed}"


def _strip_quotes(text: str) -> str:
    return text.replace("'", "")


def one_line_error(error: ValidationError, root: type[BaseModel]) -> ConfigError:
    """The first error of ``error`` (validating ``root``) as a one-line ``ConfigError``.

    Unknown-field errors come first (a misspelt key also makes its field "missing").
    """
    errors = error.errors(include_url=False)
    # A misspelt key gives "unknown field" and "missing"; the first says more.
    unknown = [item for item in errors if item["type"] == "extra_forbidden"]
    first = (unknown or errors)[0]
    kind, ctx = first["type"], first.get("ctx") or {}
    cause = ctx.get("error")
    if isinstance(cause, PhotonflowError):
        return ConfigError(str(cause))
    loc, _ = _walk(root, first["loc"])
    path = dotted(loc)
    if kind == "extra_forbidden":
        _, parent = _walk(root, first["loc"][:-1])
        known = [name for model in parent[:1] for name in model.model_fields]
        return ConfigError(_unknown_field(path, loc[-1], known))
    if kind == "missing":
        return ConfigError(f"{path}: missing")
    if kind == "union_tag_invalid":
        return ConfigError(
            f"{path}.kind = {format_value(ctx['tag'])}:"
            f" must be one of {_strip_quotes(ctx['expected_tags'])}"
        )
    if kind == "union_tag_not_found":
        _, models = _walk(root, first["loc"])
        tags = ", ".join(str(_tag(model)) for model in models)
        return ConfigError(f"{path}.kind: missing (one of {tags})")
    if kind == "literal_error":
        rule = f"must be {ctx['expected']}"
    elif kind == "value_error":
        rule = str(cause) if cause is not None else first["msg"]
    else:
        rule = _RULES.get(kind, first["msg"][:1].lower() + first["msg"][1:])
    return ConfigError(f"{path} = {format_value(first['input'])}: {rule}")
