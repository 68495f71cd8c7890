"""The largest payload a message type may take on the wire, derived from its layout.

A payload is checked against its key's bound before it is decoded, so a stranger's 100 MB "trajectory"
costs a length comparison, not seconds of CPU and a gigabyte of memory. The bound is the CDR size of
the largest message the cell can legitimately send: every sequence at its most elements and every
string at its most bytes, each field with the most alignment padding it can need. The counts are
quantities of `config/limits.yaml` and of the files that already hold them (`robot/joints.yaml`:
joints, groups, arms; `controller.yaml`: points per trajectory; `camera.yaml`: the image size).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path

from rosbags.typesys.base import Nodetype

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule
from drivers.wire.messages import WireError, typestore

CDR_ENCAPSULATION = 4        # the representation header before the message
SEQUENCE_LENGTH = 4          # uint32 element count before a sequence or a string
PRIMITIVE_BYTES = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
    "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8,
}
# The largest PNG of a W x H image: 16-bit RGBA (8 bytes a pixel) and a filter byte per row, stored
# uncompressed (zlib header and checksum, 5 bytes per stored block: zlib writes incompressible data in
# blocks of 16383 bytes at its default memory level) in IDAT chunks of 8192 bytes (libpng's, 12 bytes
# of framing each), after the signature and the IHDR and IEND chunks.
PNG_BYTES_PER_PIXEL = 8
PNG_STORED_BLOCK = 16383
PNG_STORED_BLOCK_FRAMING = 5
PNG_ZLIB_FRAMING = 6
PNG_IDAT_CHUNK = 8192
PNG_CHUNK_FRAMING = 12
PNG_FIXED_BYTES = 8 + 25 + 12  # signature, IHDR, IEND
# the counts config/limits.yaml holds; the others come from the files that define them
CONFIGURED = ("name", "reason", "text", "outline_points", "landmarks", "stage_timings", "transitions",
              "triggers", "processes", "faults", "distortion", "point_sets")


@dataclass(frozen=True)
class Quantities:
    """The counts a message's sequences and strings are bounded by (config/limits.yaml and the files
    named there), by name."""

    values: Mapping[str, int]

    def __getitem__(self, name: str) -> int:
        return self.values[name]


def png_max_bytes(width: int, height: int) -> int:
    """The largest PNG file of a `width` x `height` image (the layout above)."""
    scanlines = height * (1 + width * PNG_BYTES_PER_PIXEL)
    zlib_stream = (PNG_ZLIB_FRAMING + scanlines
                   + math.ceil(scanlines / PNG_STORED_BLOCK) * PNG_STORED_BLOCK_FRAMING)
    return PNG_FIXED_BYTES + zlib_stream + math.ceil(zlib_stream / PNG_IDAT_CHUNK) * PNG_CHUNK_FRAMING


def load_quantities(directory: Path | None = None) -> Quantities:
    """config/limits.yaml's counts plus joints, groups, arms, trajectory points and image bytes from the
    files that define them."""
    directory = directory or config_dir()
    limits = load_yaml(directory / "limits.yaml")
    # rejected: the recorder's; query_rates: load_query_rates
    limits.reject_unknown({*CONFIGURED, "image_metadata_bytes", "rejected", "query_rates"})
    values = {name: limits.int(name, min=1) for name in CONFIGURED}
    robot = load_yaml(directory / "robot" / "joints.yaml")
    values["joints"] = len(robot.items("joints"))
    values["groups"] = len(robot.items("groups"))
    values["arms"] = len(robot.items("arms"))
    values["trajectory_points"] = load_yaml(directory / "controller.yaml").int("max_points", min=1)
    camera = load_yaml(directory / "camera.yaml")
    sizes = [(camera.int("width", min=1), camera.int("height", min=1))]
    if camera.has("wrist") and camera.sub("wrist").has("table_image"):
        table_image = camera.sub("wrist").sub("table_image")
        sizes.append((table_image.int("width", min=1), table_image.int("height", min=1)))
    values["image_bytes"] = max(png_max_bytes(w, h) for w, h in sizes) + limits.int("image_metadata_bytes",
                                                                                     min=0)
    return Quantities(values)


def short_name(type_name: str) -> str:
    """`pkg/msg/Type` -> `Type`."""
    return type_name.rsplit("/", 1)[-1]


def max_cdr_size(type_name: str, counts: Mapping[str, str], quantities: Quantities,
                 default_string: str = "name") -> int:
    """The largest CDR payload of `type_name`. `counts` maps a sequence or string field, as `field` or
    `Type.field` (the latter wins), to the quantity bounding it; a string not named there is bounded by
    `default_string`, a sequence not named there is an error (every sequence must have a bound)."""

    def bound(owner: str, field: str, is_string: bool) -> int:
        quantity = counts.get(f"{short_name(owner)}.{field}") or counts.get(field)
        if quantity is None:
            if not is_string:
                raise WireError(type_name, f"{short_name(owner)}.{field} is a sequence with no bound")
            quantity = default_string
        return quantities[quantity]

    def element(owner: str, field: str, desc: tuple, in_sequence: bool = False) -> int:
        kind, detail = desc
        if kind == Nodetype.BASE:
            base = detail[0]
            if base == "string":  # the strings of a string[] are names: the field's bound is their count
                text = quantities[default_string] if in_sequence else bound(owner, field, True)
                return SEQUENCE_LENGTH + 3 + text + 1  # padding, text, NUL
            size = PRIMITIVE_BYTES[base]
            return size + size - 1
        if kind == Nodetype.NAME:
            return struct(detail)
        sub, count = detail
        if kind == Nodetype.SEQUENCE:
            return SEQUENCE_LENGTH + 3 + items(owner, field, sub, bound(owner, field, False))
        return items(owner, field, sub, count)

    def items(owner: str, field: str, sub: tuple, count: int) -> int:
        """`count` elements in a row: primitives are padded once, before the first."""
        if sub[0] == Nodetype.BASE and sub[1][0] in PRIMITIVE_BYTES:
            size = PRIMITIVE_BYTES[sub[1][0]]
            return count * size + size - 1
        return count * element(owner, field, sub, True)

    def struct(name: str) -> int:
        _, fields = typestore().fielddefs[name]
        return sum(element(name, field, desc) for field, desc in fields)

    return CDR_ENCAPSULATION + struct(type_name)


@dataclass(frozen=True)
class QueryRate:
    """How many requests a queryable answers: `burst` at once, refilled at `per_second` (a token bucket)."""

    per_second: float = rule(positive=True)
    burst: int = rule(min=1)


def load_query_rates(queryables: Collection[str], directory: Path | None = None) -> dict[str, QueryRate]:
    """config/limits.yaml `query_rates`: the rate of every key pattern in `queryables` (the registry's),
    each one required and no other allowed."""
    fields = load_yaml((directory or config_dir()) / "limits.yaml").sub("query_rates")
    fields.reject_unknown(set(queryables))
    return {key: load_fields(QueryRate, fields.sub(key)) for key in sorted(queryables)}
