"""Loading `config/` files into frozen dataclasses with errors that name file, field and reason."""

from __future__ import annotations

import builtins  # Fields has methods named str, int, float and bool: its annotations name the types
import dataclasses
import math
import os
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

CONFIG_ENV = "FOLDCELL_CONFIG_DIR"
_T = TypeVar("_T")


class ConfigError(ValueError):
    """A configuration file is missing, unreadable or holds a wrong value."""

    def __init__(self, file: str | Path, field: str, reason: str):
        self.file = str(file)
        self.field = field
        self.reason = reason
        super().__init__(f"{self.file}: {field}: {reason}" if field else f"{self.file}: {reason}")


def config_dir() -> Path:
    """The project's `config/` folder, or the one named by $FOLDCELL_CONFIG_DIR."""
    override = os.environ.get(CONFIG_ENV)
    if override:
        return Path(override)
    return Path(__file__).resolve().parents[2] / "config"


def load_yaml(path: str | Path) -> Fields:
    """Read a YAML mapping; the result hands out validated fields."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(path, "", f"cannot read: {exc.strerror or exc}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(path, "", f"not valid YAML: {yaml_problem(exc)}") from exc
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(path, "", f"top level must be a mapping, got {type(data).__name__}")
    return Fields(data, path)


def yaml_problem(exc: yaml.YAMLError) -> str:
    """A YAML syntax error on one line, where and what (PyYAML's own text spans several lines, quoting the
    source), so an error message stays the one line a command prints."""
    mark = getattr(exc, "problem_mark", None)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return where + " ".join(str(getattr(exc, "problem", None) or exc).split())


def load_yaml_over(path: str | Path | None, default: Path) -> Fields:
    """`default` with the file at `path` merged over it key by key (nested mappings too), so a file that
    sets one value leaves the others as shipped; errors name `path`. None: `default` alone."""
    base = load_yaml(default)
    if path is None or Path(path).resolve() == default.resolve():
        return base
    over = load_yaml(path)
    return Fields(_merged(base.data, over.data), Path(path))


def _merged(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in over.items():
        out[key] = _merged(base[key], value) if isinstance(value, Mapping) and isinstance(
            base.get(key), Mapping) else value
    return out


_MISSING = object()


class Fields:
    """A mapping read from a config file; each getter validates and names `file: a.b.c` on error."""

    def __init__(self, data: Mapping[builtins.str, Any], file: builtins.str | Path,
                 prefix: builtins.str = ""):
        self.data = data
        self.file = file
        self.prefix = prefix

    def path(self, name: builtins.str | builtins.int) -> builtins.str:
        if isinstance(name, int):
            return f"{self.prefix}[{name}]"
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: builtins.str | builtins.int, reason: builtins.str) -> ConfigError:
        return ConfigError(self.file, self.path(name), reason)

    def has(self, name: builtins.str) -> builtins.bool:
        return name in self.data

    def keys(self) -> list[builtins.str]:
        return [str(k) for k in self.data]

    def raw(self, name: builtins.str, default: Any = _MISSING) -> Any:
        if name not in self.data:
            if default is _MISSING:
                raise self.error(name, "missing")
            return default
        return self.data[name]

    def str(self, name: builtins.str, default: Any = _MISSING,
            choices: tuple[builtins.str, ...] | None = None) -> builtins.str:
        value = self.raw(name, default)
        if not isinstance(value, str) or not value:
            raise self.error(name, f"must be a non-empty string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(name, f"must be one of {', '.join(choices)}, got {value!r}")
        return value

    def bool(self, name: builtins.str, default: Any = _MISSING) -> builtins.bool:
        value = self.raw(name, default)
        if not isinstance(value, bool):
            raise self.error(name, f"must be true or false, got {value!r}")
        return value

    def float(self, name: builtins.str, default: Any = _MISSING, *, min: builtins.float | None = None,
              max: builtins.float | None = None, positive: builtins.bool = False) -> builtins.float:
        value = self.raw(name, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.error(name, f"must be a finite number, got {value!r}")
        value = float(value)
        if positive and value <= 0:
            raise self.error(name, f"must be > 0, got {value}")
        if min is not None and value < min:
            raise self.error(name, f"must be >= {min}, got {value}")
        if max is not None and value > max:
            raise self.error(name, f"must be <= {max}, got {value}")
        return value

    def int(self, name: builtins.str, default: Any = _MISSING, *, min: builtins.int | None = None,
            max: builtins.int | None = None) -> builtins.int:
        value = self.raw(name, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"must be an integer, got {value!r}")
        if min is not None and value < min:
            raise self.error(name, f"must be >= {min}, got {value}")
        if max is not None and value > max:
            raise self.error(name, f"must be <= {max}, got {value}")
        return value

    def floats(self, name: builtins.str, default: Any = _MISSING,
               length: builtins.int | None = None) -> tuple[builtins.float, ...]:
        value = self.raw(name, default)
        if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value
        ):
            raise self.error(name, f"must be a list of finite numbers, got {value!r}")
        if length is not None and len(value) != length:
            raise self.error(name, f"must have {length} numbers, got {len(value)}")
        return tuple(float(v) for v in value)

    def strs(self, name: builtins.str, default: Any = _MISSING) -> tuple[builtins.str, ...]:
        value = self.raw(name, default)
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) and v for v in value):
            raise self.error(name, f"must be a list of non-empty strings, got {value!r}")
        return tuple(value)

    def sub(self, name: builtins.str, default: Any = _MISSING) -> Fields:
        value = self.raw(name, {} if default is not _MISSING else _MISSING)
        if not isinstance(value, Mapping):
            raise self.error(name, f"must be a mapping, got {type(value).__name__}")
        return Fields(value, self.file, self.path(name))

    def without(self, *names: builtins.str) -> Fields:
        """This mapping less the keys `names` (read by other code)."""
        return Fields({k: v for k, v in self.data.items() if k not in names}, self.file, self.prefix)

    def items(self, name: builtins.str) -> list[Fields]:
        """A list of mappings."""
        value = self.raw(name)
        if not isinstance(value, (list, tuple)):
            raise self.error(name, f"must be a list, got {type(value).__name__}")
        out = []
        for i, item in enumerate(value):
            if not isinstance(item, Mapping):
                raise ConfigError(self.file, f"{self.path(name)}[{i}]", "must be a mapping")
            out.append(Fields(item, self.file, f"{self.path(name)}[{i}]"))
        return out

    def reject_unknown(self, allowed: set[builtins.str] | frozenset[builtins.str]) -> None:
        unknown = sorted(str(k) for k in self.data if k not in allowed)
        if unknown:
            raise self.error(unknown[0], f"unknown field (allowed: {', '.join(sorted(allowed))})")


def rule(*, min: builtins.float | None = None, max: builtins.float | None = None,
         positive: builtins.bool = False, choices: tuple[builtins.str, ...] | None = None,
         length: builtins.int | None = None, section: builtins.bool = False, under: builtins.str = "",
         default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field read from a config file by `load_fields` under its own name, checked by these
    bounds (of each number of a number list too; `length` of the list; `section`: another dataclass read
    from the sub-mapping). `under`: read from that sub-mapping instead, by its name less an `under_`
    prefix (`lease_required` under `lease` is `lease.required`). `default`: for code that builds the
    dataclass itself; a file must still name the field."""
    checks = {"min": min, "max": max, "positive": positive, "choices": choices, "length": length}
    kept = {k: v for k, v in checks.items() if v is not None and v is not False}
    return dataclasses.field(default=default, metadata={"config": kept, "section": section, "under": under})


def load_fields(cls: type[_T], f: Fields, **given: Any) -> _T:
    """The frozen dataclass `cls` from the mapping `f`: every field read by its name and typed by its
    annotation (float, int, bool, str, tuple of floats, ints or strs, or a dataclass section), checked by
    its `rule`; a key it does not name is refused. `given`: fields the caller computes instead."""
    hints = typing.get_type_hints(cls)
    fields = [fd for fd in dataclasses.fields(cls) if fd.init]  # type: ignore[arg-type]
    unders = {fd.metadata.get("under", "") for fd in fields} - {""}
    f.reject_unknown({fd.name for fd in fields if not fd.metadata.get("under")} | unders)
    subs = {under: f.sub(under) for under in sorted(unders)}
    for under, sub in subs.items():
        sub.reject_unknown({_key(fd) for fd in fields if fd.metadata.get("under") == under})
    values = dict(given)
    for fd in fields:
        if fd.name in given:
            continue
        # a field with a rule is always read; one without takes its default when the file leaves it out
        default = _MISSING if fd.default is dataclasses.MISSING or "config" in fd.metadata else fd.default
        under = fd.metadata.get("under")
        values[fd.name] = _read(subs[under] if under else f, _key(fd), hints[fd.name],
                                dict(fd.metadata.get("config", {})), default,
                                fd.metadata.get("section", False))
    return cls(**values)


def _key(fd: dataclasses.Field[Any]) -> builtins.str:
    under = fd.metadata.get("under")
    return fd.name.removeprefix(f"{under}_") if under else fd.name


def _read(f: Fields, name: builtins.str, hint: Any, checks: dict[builtins.str, Any], default: Any,
          section: builtins.bool) -> Any:
    if section:
        return load_fields(hint, f.sub(name))
    if hint is builtins.float:
        return f.float(name, default, **{k: checks[k] for k in ("min", "max", "positive") if k in checks})
    if hint is builtins.bool:
        return f.bool(name, default)
    if hint is builtins.int:
        bounds = {k: builtins.int(checks[k]) for k in ("min", "max") if k in checks}
        return f.int(name, default, **bounds)
    if hint is builtins.str:
        return f.str(name, default, choices=checks.get("choices"))
    element = typing.get_args(hint)[0] if typing.get_origin(hint) is tuple else None
    if element is builtins.str:
        return f.strs(name, default)
    if element not in (builtins.float, builtins.int):
        raise TypeError(f"{name}: no config reader for {hint!r}")
    args = typing.get_args(hint)
    numbers = f.floats(name, default, length=checks.get("length") or (None if ... in args else len(args)))
    if element is builtins.int:
        if not all(n.is_integer() for n in numbers):
            raise f.error(name, f"must be integers, got {list(numbers)}")
        numbers = tuple(builtins.int(n) for n in numbers)
    for n in numbers:
        if checks.get("positive") and n <= 0:
            raise f.error(name, f"must be > 0, got {n}")
        if "min" in checks and n < checks["min"]:
            raise f.error(name, f"must be >= {checks['min']}, got {n}")
        if "max" in checks and n > checks["max"]:
            raise f.error(name, f"must be <= {checks['max']}, got {n}")
    return numbers
