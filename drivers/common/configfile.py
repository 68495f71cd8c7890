"""Loading `config/` files into frozen dataclasses with errors that name file, field and reason."""

from __future__ import annotations

import builtins  # Fields has methods named str, int, float and bool: its annotations name the types
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

CONFIG_ENV = "FOLDCELL_CONFIG_DIR"


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
        raise ConfigError(path, "", f"not valid YAML: {exc}") from exc
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(path, "", f"top level must be a mapping, got {type(data).__name__}")
    return Fields(data, path)


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
