"""The state machine as a Mermaid diagram and a table, generated from `TRANSITIONS` (docs/statemachine.md)."""

from __future__ import annotations

from statemachine.machine import STATES, TRANSITIONS


def _guard(spec) -> str:
    parts = list(spec.conditions) + [f"not {u}" for u in spec.unless]
    return f" [{', '.join(parts)}]" if parts else ""


def mermaid() -> str:
    lines = ["stateDiagram-v2", "    [*] --> idle"]
    seen = set()
    for spec in TRANSITIONS:
        for source in spec.source:
            label = spec.trigger + _guard(spec)
            edge = (source, spec.dest, label)
            if edge not in seen:
                seen.add(edge)
                lines.append(f"    {source} --> {spec.dest}: {label}")
    return "\n".join(lines)


def markdown() -> str:
    rows = ["| trigger | from | to | guard | meaning |", "|---|---|---|---|---|"]
    for spec in TRANSITIONS:
        guard = _guard(spec).strip(" []") or "-"
        rows.append(f"| `{spec.trigger}` | {', '.join(spec.source)} | {spec.dest} | {guard} "
                    f"| {spec.description} |")
    return (
        "# The cell's state machine\n\n"
        "Generated from `statemachine/machine.py` by "
        "`python -m statemachine.diagram > docs/statemachine.md`; a test keeps it in step with the code.\n\n"
        f"States: {', '.join(f'`{s}`' for s in STATES)}.\n\n"
        "```mermaid\n" + mermaid() + "\n```\n\n" + "\n".join(rows) + "\n"
    )


if __name__ == "__main__":
    print(markdown(), end="")
