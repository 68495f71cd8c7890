"""The folder tree is the architecture: every import (at the top of a module or inside a function)
points the way the README's dependency direction says, and no two rooms import each other."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import REPO

TOP = ("tools", "cell", "statemachine", "drivers")

# the driver rooms the cell may use: every one but a controller's insides
CELL_DRIVERS = {"drivers/common", "drivers/robot", "drivers/wire", "drivers/camera", "drivers/controller",
                "drivers/sim", "drivers/sessions", "drivers/ros2"}
# room -> the rooms it may import (besides itself). A room is `top` or `top/sub` (the first folder
# below drivers/ and cell/). Rooms not listed here are a test failure: a new room states its place.
ALLOWED: dict[str, set[str]] = {
    "tools": {"*"},
    "statemachine": set(),
    "drivers": set(),  # drivers/__init__.py
    "drivers/common": set(),
    "drivers/robot": {"drivers/common"},
    "drivers/wire": {"drivers/common"},
    "drivers/camera": {"drivers/common", "drivers/robot", "drivers/wire"},
    # the protocol of a real DX100 and nothing else
    "drivers/motoros": {"drivers/common"},
    # the contract and every client of it: no client knows the emulator it may be talking to
    "drivers/controller": {"drivers/common", "drivers/robot", "drivers/wire", "drivers/motoros"},
    "drivers/emulator": {"drivers/common", "drivers/robot", "drivers/wire", "drivers/controller",
                         "drivers/motoros"},
    # the controller's contract: the world moves the arms as a controller interpolates their trajectories
    "drivers/sim": {"drivers/common", "drivers/robot", "drivers/wire", "drivers/camera",
                    "drivers/controller"},
    "drivers/sessions": {"drivers/common", "drivers/robot", "drivers/wire"},
    "drivers/ros2": {"drivers/common", "drivers/wire"},
    "cell/perception": {"drivers/common"},
    "cell/planning": {"drivers/common", "drivers/robot", "drivers/controller"},
    "cell/evaluation": {*CELL_DRIVERS, "cell/perception", "cell/planning"},
    # the cell picks a client by URL (drivers/controller/link.py) and knows no concrete controller
    "cell": {*CELL_DRIVERS, "statemachine", "cell/*"},
}
# third-party packages a room must not reach for: the state machine and the pure algorithms know no
# Zenoh, no sockets, no MCAP
FORBIDDEN_PACKAGES: dict[str, set[str]] = {
    "statemachine": {"zenoh", "mcap", "socket"},
    "cell/perception": {"zenoh", "mcap", "socket"},
    "cell/planning": {"zenoh", "mcap", "socket"},
    "drivers/common": {"zenoh", "mcap"},
}


def room_of(module: str) -> str | None:
    """`drivers.controller.codec` -> `drivers/controller`; `cell.runner` -> `cell`."""
    parts = module.split(".")
    if parts[0] not in TOP:
        return None
    if parts[0] in ("drivers", "cell") and len(parts) > 1 and (REPO / parts[0] / parts[1]).is_dir():
        return f"{parts[0]}/{parts[1]}"
    return parts[0]


def module_of(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) of every import in the file, relative ones resolved."""
    module = module_of(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            out.append((node.lineno, base))
            # `from drivers.controller import codec`: a submodule is imported too
            out += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]
    return out


def allowed(source: str, target: str) -> bool:
    if target == source:
        return True
    rules = ALLOWED[source]
    return "*" in rules or target in rules or any(
        r.endswith("/*") and target.startswith(r[:-1]) for r in rules)


def source_files() -> list[Path]:
    return sorted(p for top in TOP for p in (REPO / top).rglob("*.py"))


def test_every_room_has_a_place() -> None:
    rooms = {room_of(module_of(p)) for p in source_files()}
    assert rooms <= set(ALLOWED), f"rooms without a rule in ALLOWED: {sorted(rooms - set(ALLOWED))}"


@pytest.mark.parametrize("path", source_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_imports_point_the_way_of_the_architecture(path: Path) -> None:
    source = room_of(module_of(path))
    assert source is not None
    wrong = []
    for line, target_module in imports_of(path):
        target = room_of(target_module)
        if target is not None and not allowed(source, target):
            wrong.append(f"line {line}: {source} imports {target_module} ({target})")
        first = target_module.split(".")[0]
        if first in FORBIDDEN_PACKAGES.get(source, ()):
            wrong.append(f"line {line}: {source} must not use {first}")
    assert not wrong, "\n".join(wrong)


def test_no_two_rooms_import_each_other() -> None:
    edges: set[tuple[str, str]] = set()
    for path in source_files():
        source = room_of(module_of(path))
        for _, target_module in imports_of(path):
            target = room_of(target_module)
            if target is not None and target != source:
                edges.add((str(source), target))
    mutual = sorted((a, b) for a, b in edges if (b, a) in edges and a < b)
    assert not mutual, f"rooms importing each other: {mutual}"


def test_the_checker_sees_a_wrong_import(tmp_path: Path) -> None:
    """The rules catch what they are for (a driver reaching into perception, a lazy one included)."""
    assert not allowed("drivers/sim", "cell/perception")
    assert not allowed("drivers/controller", "drivers/emulator")
    assert not allowed("cell", "drivers/emulator") and not allowed("cell", "drivers/motoros")
    assert not allowed("drivers/motoros", "drivers/controller")
    assert not allowed("statemachine", "drivers/wire")
    assert allowed("cell", "drivers/controller") and allowed("tools", "cell/perception")
    assert room_of("drivers.controller.codec") == "drivers/controller" and room_of("cell.runner") == "cell"
