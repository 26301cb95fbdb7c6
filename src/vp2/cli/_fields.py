"""Command-line flags generated from the fields of a config dataclass, for every ``vp2`` command.

A command describes each field of its config once, in a mapping ``field name -> Flag`` in the
order ``--help`` lists the flags: ``"planner.num_samples"`` names a field of a nested dataclass
(one level), :data:`NOT_A_FLAG` a field without a flag, and a ``Flag(cli_only=True)`` a flag of
the command that is no field. :func:`add_flags` adds the flags to a parser and :func:`build`
makes the dataclass from the parsed arguments.

A flag's type (``int``, ``float``), default, ``nargs="+"`` (a tuple or list field) and
``store_true`` (a ``bool`` field) come from its field unless the :class:`Flag` says otherwise,
so a default is written once, in the dataclass. Every field needs an entry: a field added to a
config without a decision about its flag is an error when the parser is built (and in the CLI
tests).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from typing import Any

#: The entry of a field that has no flag (it keeps its default, or :func:`build` gets it).
NOT_A_FLAG = None


class _FromField:
    def __repr__(self) -> str:
        return "FROM_FIELD"


#: ``Flag.default``: the field's default.
FROM_FIELD: Any = _FromField()


@dataclasses.dataclass(frozen=True)
class Flag:
    """How a field appears on the command line; unset attributes come from the field.

    Attributes:
        name: ``"--num-samples"`` (default: ``--`` and the field's name with dashes), or the
            name of a positional argument (no dashes).
        short: A short alias, e.g. ``"-n"``.
        help: The help text.
        metavar: As in ``add_argument``.
        choices: As in ``add_argument``.
        type: Parses one value (default: ``int`` or ``float`` for such a field).
        nargs: As in ``add_argument`` (default: ``"+"`` for a tuple or list field).
        action: As in ``add_argument`` (default: ``"store_true"`` for a ``bool`` field).
        default: The parser's default (default: the field's).
        required: As in ``add_argument``.
        group: Title of the argument group the flag is listed in (groups in first-use order).
        negate: A ``store_true`` flag that sets the boolean field to ``False`` (``--no-gifs``
            for ``save_gifs``).
        convert: Makes the field's value of the parsed one (default: a list becomes a tuple
            for a tuple field).
        cli_only: A flag of the command that is no field: :func:`build` skips it.
    """

    name: str | None = None
    short: str | None = None
    help: str | None = None
    metavar: str | tuple[str, ...] | None = None
    choices: Sequence[Any] | None = None
    type: Callable[[str], Any] | None = None
    nargs: str | int | None = None
    action: str | type[argparse.Action] | None = None
    default: Any = FROM_FIELD
    required: bool = False
    group: str | None = None
    negate: bool = False
    convert: Callable[[Any], Any] | None = None
    cli_only: bool = False


Flags = Mapping[str, "Flag | None"]


@dataclasses.dataclass(frozen=True)
class _Field:
    """A (possibly nested) field: the dataclass field, its annotation (``None`` where it
    cannot be resolved) and, for a nested dataclass, its class."""

    field: dataclasses.Field[Any]
    annotation: Any
    nested: type | None


def add_flags(parser: argparse.ArgumentParser, cls: type | None, flags: Flags) -> None:
    """Adds a flag per entry of ``flags`` to ``parser`` (or to its argument groups).

    Args:
        parser: The command's parser.
        cls: The config dataclass (``None``: every entry is ``cli_only``).
        flags: ``field name -> Flag | NOT_A_FLAG`` in the order of ``--help`` (module
            docstring).

    Raises:
        ValueError: a field without an entry, or an entry that names no field.
    """
    fields = _fields(cls)
    _check_entries(cls, fields, flags)
    groups: dict[str, argparse._ArgumentGroup] = {}
    for key, flag in flags.items():
        if flag is NOT_A_FLAG:
            continue
        target: argparse._ActionsContainer = parser
        if flag.group is not None:
            if flag.group not in groups:
                groups[flag.group] = parser.add_argument_group(flag.group)
            target = groups[flag.group]
        name = _name(key, flag)
        names = [flag.short, name] if flag.short else [name]
        target.add_argument(*names, **_argparse_kwargs(flag, fields.get(key), name))


def build(cls: type, args: argparse.Namespace, flags: Flags, **values: Any) -> Any:
    """The ``cls`` instance of parsed arguments: each field from its flag, or from
    ``values`` (fields without a flag, or whose value the command works out itself; a nested
    dataclass field given whole replaces its flags)."""
    fields = _fields(cls)
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for key, flag in flags.items():
        if flag is NOT_A_FLAG or flag.cli_only:
            continue
        parent, _, child = key.rpartition(".")
        if key in values or parent in values:
            continue
        value = _field_value(getattr(args, dest(key, flag)), flag, fields[key])
        if parent:
            nested.setdefault(parent, {})[child] = value
        else:
            top[key] = value
    for parent, sub in nested.items():
        nested_cls = fields[parent].nested
        assert nested_cls is not None
        top[parent] = nested_cls(**sub)
    return cls(**top, **values)


def dest(key: str, flag: Flag) -> str:
    """The attribute of the parsed arguments that holds the flag's value."""
    name = _name(key, flag)
    return name.lstrip("-").replace("-", "_") if name.startswith("-") else name


# --------------------------------------------------------------------------- internals


def _name(key: str, flag: Flag) -> str:
    return flag.name or "--" + key.rpartition(".")[2].replace("_", "-")


def _fields(cls: type | None) -> dict[str, _Field]:
    """``name -> _Field`` of every field, and ``"parent.child"`` of nested dataclasses."""
    if cls is None:
        return {}
    out = {}
    for f in dataclasses.fields(cls):
        nested = _nested_class(f)
        out[f.name] = _Field(f, _annotation(cls, f), nested)
        if nested is not None:
            for g in dataclasses.fields(nested):
                out[f"{f.name}.{g.name}"] = _Field(g, _annotation(nested, g), None)
    return out


def _check_entries(cls: type | None, fields: dict[str, _Field], flags: Flags) -> None:
    name = getattr(cls, "__name__", "the command")
    missing = []
    for key, info in fields.items():
        parent = key.rpartition(".")[0]
        if key in flags or (parent and parent in flags):
            continue
        if info.nested is not None and any(k.startswith(f"{key}.") for k in flags):
            continue
        missing.append(key)
    if missing:
        raise ValueError(f"{name} field(s) {missing} have no entry (a Flag or NOT_A_FLAG)")
    unknown = [k for k, f in flags.items() if k not in fields and not (f and f.cli_only)]
    if unknown:
        raise ValueError(f"{name} has no field(s) {unknown} (a command's own flag: cli_only)")


def _nested_class(f: dataclasses.Field[Any]) -> type | None:
    if f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        value = f.default
    return type(value) if dataclasses.is_dataclass(value) else None


def _annotation(cls: type, f: dataclasses.Field[Any]) -> Any:
    """The field's annotation as an object; ``None`` if it names something imported only for
    type checking."""
    if not isinstance(f.type, str):
        return f.type
    module = sys.modules.get(cls.__module__)
    try:
        return eval(f.type, dict(vars(module)) if module else {})  # what get_type_hints does
    except Exception:
        return None


def _shape(annotation: Any) -> tuple[type | None, Any]:
    """``(tuple or list or None, the value type)`` of an annotation, ``None`` removed from it."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        rest = [a for a in typing.get_args(annotation) if a is not type(None)]
        annotation = rest[0] if len(rest) == 1 else None
    origin = typing.get_origin(annotation)
    if origin in (tuple, list):
        return origin, typing.get_args(annotation)[0]
    return None, annotation


def _field_default(info: _Field | None) -> Any:
    if info is None:
        return None
    f = info.field
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _argparse_kwargs(flag: Flag, info: _Field | None, name: str) -> dict[str, Any]:
    container, value_type = _shape(info.annotation) if info is not None else (None, None)
    default = _field_default(info) if flag.default is FROM_FIELD else flag.default
    kwargs: dict[str, Any] = {}
    if flag.negate:
        kwargs["action"] = "store_true"
    elif flag.action is None and value_type is bool and container is None and flag.type is None:
        if default:
            raise ValueError(f"{name}: a bool field that defaults to True needs negate=True")
        kwargs["action"] = "store_true"
    else:
        inferred = flag.action is None  # an action of the flag's own takes no inferred values
        if flag.action is not None:
            kwargs["action"] = flag.action
        kind = flag.type or (value_type if inferred and value_type in (int, float) else None)
        if kind is not None:
            kwargs["type"] = kind
        nargs = flag.nargs or ("+" if inferred and container is not None else None)
        if nargs is not None:
            kwargs["nargs"] = nargs
        if name.startswith("-"):
            kwargs["default"] = default
    for key in ("choices", "metavar", "help"):
        if getattr(flag, key) is not None:
            kwargs[key] = getattr(flag, key)
    if flag.required:
        kwargs["required"] = True
    return kwargs


def _field_value(value: Any, flag: Flag, info: _Field) -> Any:
    if flag.negate:
        return not value
    if flag.convert is not None:
        return flag.convert(value)
    if _shape(info.annotation)[0] is tuple and isinstance(value, list):
        return tuple(value)
    return value
