"""A test node: re-publishes every message it receives in cell `src` on the same key in cell `dst`,
and answers every queryable of cell `dst` with a reply that carries the request back as text."""

from __future__ import annotations

import json
import sys

import numpy as np

from drivers.wire import messages
from drivers.wire.registry import KEYS
from drivers.wire.transport import Wire
from tests.wire.examples import concrete_key, random_message
from tools.common import StopSignal, add_wire_arguments, setup_logging, wire_settings


def main() -> int:
    import argparse

    parser = argparse.ArgumentParser()
    add_wire_arguments(parser)
    parser.add_argument("--dst", required=True)
    args = parser.parse_args()
    setup_logging(0)
    stop = StopSignal()
    settings = wire_settings(args, "player")
    with Wire(settings, "mirror") as wire:
        out_settings = settings.overridden(cell_id=args.dst)
        with Wire(out_settings, "mirror-out") as out:
            pubs = {concrete_key(s.pattern): out.publisher(concrete_key(s.pattern))
                    for s in KEYS if s.kind == "pub"}

            def forward(key: str, msg, _raw) -> None:
                rel = key.split("/", 2)[2]
                pubs[rel].put(msg)

            def bad(err) -> None:
                print(f"mirror: bad sample: {err}", file=sys.stderr, flush=True)

            for rel in pubs:
                wire.subscribe(rel, forward, on_error=bad)

            rng = np.random.default_rng(0)

            def make_handler(spec):
                def handle(request, _info):
                    reply = random_message(spec.reply_type, rng)
                    text = json.dumps(messages.to_dict(request), default=str)
                    for field in ("text", "format"):
                        if hasattr(reply, field):
                            setattr(reply, field, text if field == "text" else "png;" + text[:40])
                    return reply
                return handle

            for spec in KEYS:
                if spec.kind == "queryable":
                    out.serve(spec.pattern, make_handler(spec))
            print("mirror ready", flush=True)
            stop.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
