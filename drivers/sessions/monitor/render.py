"""A monitor snapshot as terminal text (optionally with ANSI colours). Pure."""

from __future__ import annotations

import textwrap
from collections.abc import Callable
from typing import Any

BAR_WIDTH = 20  # characters of a joint's range bar
RED, YELLOW, GREEN, DIM, BOLD, RESET = "\x1b[31m", "\x1b[33m", "\x1b[32m", "\x1b[2m", "\x1b[1m", "\x1b[0m"


def _flag(value: Any, yes: str, no: str, colour: bool, bad_when: bool | None = None) -> str:
    text = "?" if value is None else (yes if value else no)
    if colour and bad_when is not None and value is bad_when:
        return f"{RED}{text}{RESET}"
    return text


def _bar(fraction: float) -> str:
    pos = min(BAR_WIDTH - 1, max(0, round(fraction * (BAR_WIDTH - 1))))
    return "[" + "".join("|" if i == pos else "-" for i in range(BAR_WIDTH)) + "]"


def _duration(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    return f"{minutes}:{secs:02d}" if minutes else f"{seconds:.1f} s"


def render_text(
    snap: dict[str, Any], *, colour: bool = False, width: int = 100, status: str = "", live: bool = True
) -> list[str]:
    """Lines for one snapshot: per cell its state, controller, joints, topics, processes, errors;
    `status` (the keys, a question, a command's reply) under the title; `live`: the screen redrawn
    until q (not one snapshot printed)."""
    c = _painter(colour)
    quits = "   (q quits)" if live else ""
    lines = [c(BOLD, f"foldcell monitor - watching {snap['watching']}   samples {snap['samples']}{quits}")]
    if status:
        lines.append(c(YELLOW, status[:width]))
    if not snap["cells"]:
        lines.append("no cell seen yet")
    for cell in snap["cells"].values():
        tag = (
            "GONE"
            if cell["gone"]
            else ("replay" if cell["replay"] else ("alive" if cell["alive"] else "no token"))
        )
        tag_c = RED if cell["gone"] else (YELLOW if cell["replay"] else GREEN)
        lines.append("")
        lines.append(c(BOLD, f"cell {cell['cell']}") + "  " + c(tag_c, tag))
        lines += _state_lines(cell, c, width)
        lines += _robot_lines(cell, c, colour, width)
        lines += _traffic_lines(cell, c, colour, width)
    return lines


def _painter(colour: bool) -> Callable[[str, str], str]:
    """`paint(code, text)`: the text in an ANSI colour, or as it is."""
    if colour:
        return lambda code, text: f"{code}{text}{RESET}"
    return lambda _code, text: text


def _state_lines(cell: dict[str, Any], c: Callable[[str, str], str], width: int) -> list[str]:
    """The cell's state, garment, fold and stage, its reason, its folds and its recent history."""
    st = cell["state"]
    if not st:
        return []
    fold_s = cell["fold_elapsed_s"]
    step = (f"fold {st['fold_index']}/{st['fold_count']}"
            + (f" {_duration(fold_s)}" if fold_s is not None else "") + f" attempt {st['attempt']}")
    elapsed = cell["garment_elapsed_s"]
    garment = (st["garment"] or "-") + (f" {_duration(elapsed)}" if elapsed is not None else "")
    lines = [f"  state {c(BOLD, st['state'])}  garment {garment}  {step}  stage {st['stage'] or '-'}"]
    if st["reason"]:
        later = f" (since: {st['later_reason']})" if st["later_reason"] else ""
        lines += _wrapped(f"reason: {st['reason']}{later}", width)
    if cell["folds"]:
        lines.append("  folds " + "  ".join(
            f"{f['fold']}: {_duration(f['elapsed_s'])} {f['outcome'] or 'in work'}" for f in cell["folds"]))
    hist = " > ".join(t["dest"] for t in st["history"][-8:])
    if hist:
        lines.append(f"  history {hist}"[:width])
    return lines


def _robot_lines(cell: dict[str, Any], c: Callable[[str, str], str], colour: bool, width: int) -> list[str]:
    """The controller's status, the grippers and every joint against its limits."""
    lines = []
    ctl = cell["controller"]
    if ctl:
        alarm_text = f"ALARM {ctl['alarm_code']} {ctl['alarm_text']}"
        alarm = _flag(ctl["alarm"], alarm_text, "no alarm", colour, True)
        lines.append(
            f"  controller servo {_flag(ctl['servo'], 'on', 'off', colour, False)}"
            f"  e-stop {_flag(ctl['e_stop'], 'PRESSED', 'released', colour, True)}  {alarm}"
            f"  motion {_flag(ctl['in_motion'], 'moving', 'still', False)}  mode {ctl['mode']}"
            f"  lease {ctl['lease_holder'] or '-'}"
            + (f"  loop stalls {ctl['loop_stalls']}" if ctl["loop_stalls"] else "")
        )
        if not ctl["lease_holder"] and ctl["lease_note"]:
            lines.append(f"  lease lost: {ctl['lease_note']}"[:width])
    if cell["grippers"]:
        lines.append("  grippers " + "  ".join(
            f"{arm} {'closed' if g['closed'] else 'open'} {g['opening_m'] * 1e3:.0f} mm"
            for arm, g in cell["grippers"].items()))
    for j in cell["joints"]:
        if "fraction" in j:
            warn = j["outside"] or j["near_limit"]
            limits = f"[{j['lower']:+.2f}, {j['upper']:+.2f}]"
            text = f"  {j['name']:12s} {j['position']:+8.3f} {_bar(j['fraction'])} {limits}"
            lines.append(c(RED, text) if warn and colour else text + ("  LIMIT" if warn else ""))
        else:
            lines.append(f"  {j['name']:12s} {j['position']:+8.3f}")
    return lines


def _traffic_lines(cell: dict[str, Any], c: Callable[[str, str], str], colour: bool, width: int) -> list[str]:
    """The topics with their rates, the processes (and those gone), the tools, the last errors."""
    lines = []
    if cell["topics"]:
        lines.append(c(DIM, f"  {'topic':32s} {'rate':>9s} {'age':>8s} {'count':>8s} bad"))
        for rel, t in cell["topics"].items():
            text = f"  {rel:32s} {t['rate_hz']:7.1f}Hz {t['age_s']:7.2f}s {t['count']:8d} {t['bad']}"
            lines.append(c(DIM, text) if t["stale"] and colour else text)
    gone = ", ".join(f"{p['name']} ({p['ago_s']:.1f} s ago{', the cell lost it' if p['cell_lost'] else ''})"
                     for p in cell["processes_gone"])
    lines.append(f"  processes {', '.join(cell['processes']) or '-'}" + (f"   gone: {gone}" if gone else ""))
    if cell["tools"]:
        lines.append(c(DIM, f"  tools {', '.join(cell['tools'])}"))
    for e in cell["errors"][-5:]:
        times = f"{e['count']}x, last {e['last_time']}" if e["count"] > 1 else e["last_time"]
        lines += [c(RED, text) for text in
                  _wrapped(f"error [{e['source']}] ({times}) {e['where']}: {e['text']}", width)]
    return lines


def _wrapped(text: str, width: int) -> list[str]:
    """`text` indented under its cell, its continuation lines further: a long error is read whole."""
    return textwrap.wrap(text, width=max(width, 40), initial_indent="  ", subsequent_indent="    ",
                         break_on_hyphens=False) or ["  "]
