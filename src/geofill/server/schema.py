"""The fill configuration as the server shows it: one flat list of fields, and a pydantic model for
the OpenAPI page, both derived from :class:`geofill.config.FillConfig` (its types, defaults and
each field's description, ``metadata["help"]``), so that nothing is copied by hand and a new config
key appears everywhere.

Validation is not done here: a request's config goes through ``FillConfig.updated`` like the CLI's
``--set``, so the server accepts exactly what the CLI accepts and its errors name the same keys."""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from ..config import Cost, FillConfig, Length, Range, ServerOnly, marked_keys
from ..errors import ConfigError

#: The keys the page offers first, in this order: what a user changes before anything else (what
#: is done with a removed object the references show, how the rest is painted, the depth, the colour
#: match, a known focal length, the speed/detail trade-off). The others are grouped by section.
COMMON_KEYS = (
    "screen.removed_object",
    "inpaint.method",
    "depth.backend",
    "refine.colour",
    "intrinsics.focal_px",
    "working_max_side",
)


@dataclass(frozen=True)
class ConfigField:
    """One leaf of the configuration, as the page's advanced options show it."""

    key: str  # dotted, e.g. "depth.backend"
    kind: str  # "bool" | "int" | "float" | "str" | "choice" | "list" (JSON-typed in the form)
    default: Any
    optional: bool  # None is allowed
    choices: tuple[Any, ...]  # for "choice"
    description: str
    section: str  # "" for top-level keys
    locked: bool  # set by the server's operator only
    range: Range | None = None  # a number's bounds; for a list, each item's
    length: Length | None = None  # a list's number of items
    cost: Cost | None = None  # larger values cost more: capped by the server


def _extras(tp: Any) -> tuple[Any, tuple[Any, ...]]:
    """(``tp`` without ``Annotated``, its ``Annotated`` metadata)."""
    if typing.get_origin(tp) is Annotated:
        return typing.get_args(tp)[0], tp.__metadata__
    return tp, ()


def _first(metadata: tuple[Any, ...], kind: type) -> Any:
    return next((m for m in metadata if isinstance(m, kind)), None)


def _kind(tp: Any) -> tuple[str, bool, tuple[Any, ...], Range | None, Length | None]:
    """(kind, optional, choices, range, length) of a config type hint (with its extras)."""
    optional = False
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        optional = len(args) < len(typing.get_args(tp))
        tp = args[0] if len(args) == 1 else tp
    tp, metadata = _extras(tp)
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "choice", optional, typing.get_args(tp), None, None
    if origin in (list, tuple):
        _, item_metadata = _extras((typing.get_args(tp) or (Any,))[0])
        return "list", optional, (), _first(item_metadata, Range), _first(metadata, Length)
    names = {bool: "bool", int: "int", float: "float", str: "str"}
    return names.get(tp, "str"), optional, (), _first(metadata, Range), None


@functools.cache
def config_fields(root: type = FillConfig) -> tuple[ConfigField, ...]:
    """Every leaf of ``root`` (a config dataclass: :class:`FillConfig`), sections first in
    declaration order."""
    out: list[ConfigField] = []
    costs, server_only = marked_keys(Cost, root), marked_keys(ServerOnly, root)

    def walk(cls: type, defaults: Any, prefix: str) -> None:
        hints = typing.get_type_hints(cls, include_extras=True)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            value = getattr(defaults, f.name)
            if dataclasses.is_dataclass(tp):
                walk(tp, value, f"{prefix}{f.name}.")
                continue
            kind, optional, choices, bounds, length = _kind(tp)
            key = f"{prefix}{f.name}"
            # Locked by type, never by a list of names: a ServerOnly field (a path on the server's
            # machine, a download switch, the server's pixel limit) or free text (it can name a file).
            section, locked = prefix[:-1], key in server_only or kind == "str"
            out.append(
                ConfigField(
                    key,
                    kind,
                    value,
                    optional,
                    choices,
                    f.metadata["help"],
                    section,
                    locked,
                    bounds,
                    length,
                    costs.get(key),
                )
            )

    walk(root, root(), "")
    return tuple(out)


@functools.cache
def locked_keys() -> frozenset[str]:
    """Keys a request may not set: only whoever starts the server does (``geofill serve
    --config/--set``)."""
    return frozenset(f.key for f in config_fields() if f.locked)


@functools.cache
def config_sections() -> tuple[tuple[str, str], ...]:
    """(name, description) of each section of :class:`FillConfig` in declaration order (the
    pipeline's), the description being the section class's docstring on one line."""
    hints = typing.get_type_hints(FillConfig)
    return tuple(
        (f.name, " ".join((hints[f.name].__doc__ or "").split()))
        for f in dataclasses.fields(FillConfig)
        if dataclasses.is_dataclass(hints[f.name])
    )


def flatten(data: Any, where: str = "config") -> dict[str, Any]:
    """A request's config object, nested (``{"depth": {"backend": "stereo"}}``) or dotted
    (``{"depth.backend": "stereo"}``), as dotted overrides."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a JSON object, got {type(data).__name__}")
    out: dict[str, Any] = {}
    for key, value in data.items():
        dotted = key if where == "config" else f"{where[len('config.') :]}.{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"config.{dotted}"))
        else:
            out[dotted] = value
    return out


def value_at(data: dict[str, Any], key: str) -> Any:
    """The value of dotted ``key`` in a nested config dict (``FillConfig.to_dict()``)."""
    for part in key.split("."):
        data = data[part]
    return data


def _over(value: Any, cap: float, cost: Cost) -> bool:
    """Whether ``value`` (a list: any item) costs more than ``cap`` allows."""
    if cost.zero_is_most and cap == 0:  # the cap is "no limit"
        return False
    return any(
        v > cap or (cost.zero_is_most and v == 0) for v in (value if isinstance(value, list) else [value])
    )


def _number(x: float) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def server_caps(base: FillConfig, explicit: Mapping[str, Any]) -> tuple[FillConfig, dict[str, float]]:
    """(``base`` lowered to the caps, the cap of every cost key) of a server whose fills default to
    ``base``: ``explicit`` (``geofill serve --cap KEY=VALUE``) where given, else ``base``'s own value
    (a list's: its largest item), so that a request may lower a cost but never raise it. ConfigError
    names a key that is not a cost or a cap that is not a number."""
    costs = {f.key: f for f in config_fields() if f.cost}
    for key, cap in explicit.items():
        if key not in costs:
            raise ConfigError(
                f"--cap {key}: not a setting that scales a fill's cost; those are: {', '.join(costs)}"
            )
        whole = costs[key].kind != "float"
        if isinstance(cap, bool) or not isinstance(cap, int | float) or not math.isfinite(cap) or cap < 0:
            raise ConfigError(f"--cap {key}: expected a number >= 0, got {cap!r}")
        if whole and cap != int(cap):
            raise ConfigError(f"--cap {key}: expected a whole number, got {cap!r}")
    data = base.to_dict()
    caps: dict[str, float] = {}
    lowered: dict[str, Any] = {}
    for key, f in costs.items():
        value = value_at(data, key)
        cap = explicit.get(key, max(value) if isinstance(value, list) else value)
        caps[key] = int(cap) if f.kind != "float" else float(cap)
        if _over(value, caps[key], f.cost):
            lowered[key] = [min(v, caps[key]) for v in value] if isinstance(value, list) else caps[key]
    return (base.updated(lowered) if lowered else base), caps


def apply_request_config(base: FillConfig, data: Any, caps: Mapping[str, float] | None = None) -> FillConfig:
    """``base`` with a request's overrides; ConfigError names the offending key: one only the
    server sets, or a cost over its cap in ``caps`` (from :func:`server_caps`)."""
    overrides = flatten(data)
    locked = sorted(k for k in overrides if k in locked_keys())
    if locked:
        raise ConfigError(f"config key '{locked[0]}' can only be set by whoever starts the server")
    cfg = base.updated(overrides) if overrides else base
    values = cfg.to_dict()
    for f in config_fields():
        if f.cost and f.key in (caps or {}) and _over(value := value_at(values, f.key), caps[f.key], f.cost):
            shown = "0 (no limit)" if f.cost.zero_is_most and value == 0 else _number(value)
            raise ConfigError(
                f"config key '{f.key}': {shown} is over this server's cap of {_number(caps[f.key])} "
                "(a request may lower it, not raise it)"
            )
    return cfg


@functools.cache
def config_model() -> type:
    """A pydantic model mirroring :class:`FillConfig` with its fields' descriptions, for OpenAPI."""
    from pydantic import Field, create_model

    def build(cls: type) -> type:
        hints = typing.get_type_hints(cls)
        defaults = cls()
        fields: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            if dataclasses.is_dataclass(tp):
                fields[f.name] = (build(tp), Field(default_factory=tp, description=tp.__doc__))
            else:
                default = getattr(defaults, f.name)
                fields[f.name] = (tp, Field(default=default, description=f.metadata["help"]))
        return create_model(cls.__name__, __doc__=cls.__doc__, **fields)

    return build(FillConfig)


def with_config_schema(openapi: dict[str, Any], path: str) -> dict[str, Any]:
    """``openapi`` (a generated OpenAPI document) with :func:`config_model`'s schema as the
    response of ``GET path`` and its sections among the components."""
    schema = config_model().model_json_schema(ref_template="#/components/schemas/{model}")
    components = openapi.setdefault("components", {}).setdefault("schemas", {})
    components.update(schema.pop("$defs", {}))
    components[schema["title"]] = schema
    ok = openapi["paths"][path]["get"]["responses"]["200"]
    ok["content"] = {"application/json": {"schema": {"$ref": f"#/components/schemas/{schema['title']}"}}}
    return openapi
