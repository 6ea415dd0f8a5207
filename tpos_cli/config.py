"""Pipeline files: declarative TOML, validated against the chain's frozen parameter dataclass.

A pipeline file names a chain from the fixed registry in `tpos_cli.pipeline`; nothing a file names
is imported or evaluated.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
import types
import typing
from dataclasses import dataclass
from pathlib import Path

from tpos_cli.errors import InvalidInputError

PIPELINES_DIR = Path(__file__).resolve().parent.parent / "pipelines"


@dataclass(frozen=True)
class PipelineFile:
    name: str
    description: str
    chain: str
    kinds: tuple
    params: dict
    path: Path


def pipelines_dir() -> Path:
    """The folder of bundled pipelines (next to the package in a checkout or editable install)."""
    return PIPELINES_DIR


def list_pipelines() -> list[PipelineFile]:
    return [load_pipeline_file(p) for p in sorted(pipelines_dir().glob("*.toml"))]


def resolve_pipeline(name_or_path: str | Path | None, kind: str) -> PipelineFile:
    """A pipeline by bundled name, by path, or (None) the default for a session kind."""
    if name_or_path is None:
        for p in list_pipelines():
            if kind in p.kinds:
                return p
        raise InvalidInputError(f"no pipeline in {pipelines_dir()} is the default for sessions of kind {kind!r}; pass -p")
    cand = Path(name_or_path)
    if cand.suffix == ".toml" or cand.exists():
        if not cand.exists():
            raise InvalidInputError(f"{cand}: pipeline file not found")
        return load_pipeline_file(cand)
    path = pipelines_dir() / f"{name_or_path}.toml"
    if not path.exists():
        names = ", ".join(p.stem for p in sorted(pipelines_dir().glob("*.toml")))
        raise InvalidInputError(f"unknown pipeline {name_or_path!r} (bundled: {names})")
    return load_pipeline_file(path)


def load_pipeline_file(path: Path) -> PipelineFile:
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInputError(f"{path.name}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise InvalidInputError(f"{path}: cannot be read ({exc.strerror})") from None
    head = raw.get("pipeline")
    if not isinstance(head, dict):
        raise InvalidInputError(f"{path.name}: [pipeline] section with name, description, chain is required")
    unknown = set(head) - {"name", "description", "chain", "kinds"}
    if unknown:
        raise InvalidInputError(f"{path.name}: [pipeline] unknown key {sorted(unknown)[0]!r}")
    for key in ("name", "chain"):
        if not isinstance(head.get(key), str):
            raise InvalidInputError(f"{path.name}: [pipeline] {key} must be a string")
    params = {k: v for k, v in raw.items() if k != "pipeline"}
    return PipelineFile(
        name=head["name"], description=str(head.get("description", "")), chain=head["chain"],
        kinds=tuple(head.get("kinds", ())), params=params, path=path,
    )


def apply_overrides(params: dict, overrides: dict) -> dict:
    """Dotted overrides (`section.key = value`) onto a parameter dict (a copy)."""
    out = json.loads(json.dumps(params))
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise InvalidInputError(f"override {dotted!r}: {p!r} is not a section")
        node[parts[-1]] = value
    return out


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


T = typing.TypeVar("T")


def parse_params(cls: type[T], section: dict | None, where: str) -> T:
    """Build frozen dataclass `cls` from a TOML section; unknown keys and wrong types are errors."""
    section = dict(section or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(section) - set(fields))
    if unknown:
        raise InvalidInputError(f"pipeline [{where}]: unknown key {unknown[0]!r} (known: {', '.join(sorted(fields))})")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, value in section.items():
        sub = hints[name]
        if dataclasses.is_dataclass(sub):
            kwargs[name] = parse_params(sub, value, f"{where}.{name}")
            continue
        kwargs[name] = _coerce(value, sub, f"{where}.{name}")
    return cls(**kwargs)


def _coerce(value, typ, where):
    origin = typing.get_origin(typ)
    args = typing.get_args(typ)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, where)
            except InvalidInputError as exc:
                errors.append(exc)
        raise errors[0]
    if origin is typing.Literal:
        if value not in args:
            raise InvalidInputError(f"pipeline [{where}]: must be one of {', '.join(map(repr, args))}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise InvalidInputError(f"pipeline [{where}]: must be a list, got {value!r}")
        inner = args[0] if args else typing.Any
        return tuple(_coerce(v, inner, where) for v in value) if origin is tuple else [_coerce(v, inner, where) for v in value]
    if origin is dict:
        if not isinstance(value, dict):
            raise InvalidInputError(f"pipeline [{where}]: must be a table, got {value!r}")
        return dict(value)
    if typ is typing.Any:
        return value
    if typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidInputError(f"pipeline [{where}]: must be a number, got {value!r}")
        return float(value)
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise InvalidInputError(f"pipeline [{where}]: must be an integer, got {value!r}")
        return value
    if typ is bool:
        if not isinstance(value, bool):
            raise InvalidInputError(f"pipeline [{where}]: must be true or false, got {value!r}")
        return value
    if typ is str:
        if not isinstance(value, str):
            raise InvalidInputError(f"pipeline [{where}]: must be a string, got {value!r}")
        return value
    return value


def params_to_dict(params) -> dict:
    """The fully resolved parameters (defaults included) for summary.json."""
    return json.loads(json.dumps(dataclasses.asdict(params), default=str))
