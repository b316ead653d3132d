"""``softplc chronogram TRACE.jsonl -o OUT.svg``: a trace drawn as a timing diagram (SVG).

The trace is the one ``softplc simulate --trace`` writes: one JSON object per scan with
``cycle``, ``t_ms`` and ``instance.signal`` keys (language.md). Bools are square waves,
numbers and texts are value bands. Without ``--signals``, every instance shows its inputs,
its step activity (``.X``), its outputs and its memory, grouped in that order, using the seed's
prefixes (``i``, ``gs``/``.X``, ``o``, ``s``). ``--signals`` takes keys (``tester1.iMarcha``),
glob patterns (``tester1.gs*.X``) or names without the instance (``iMarcha``: every
instance's). ``--cycle K`` draws a cursor at scan K. ``--plant PLANT.yaml`` takes the groups
and the types from the plant's charts instead of guessing them from the names and values.

Pure Python, no dependency: it runs on the controller.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import re
import sys
from dataclasses import dataclass
from typing import Any

from drivers.durations import parse_literal, strip_time_prefix
from runtime.drawing.svg import Svg, esc, esc_attr
from runtime.errors import Loc, SourceError

ROW_H = 18.0
ROW_GAP = 8.0
HIGH_FILL = "#c8e6c9"
STEP_FILL = "#ffe082"
BAND_FILL = "#e3f2fd"
CHAR_W = 6.6  # average width of a character at 11 px


def load_trace(path: str) -> list[dict[str, Any]]:
    rows = []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line:
                continue
            try:
                r = json.loads(line)
            except json.JSONDecodeError as exc:
                raise SourceError(Loc(path, n, exc.colno), f"bad JSON: {exc.msg}") from None
            if not isinstance(r, dict) or "t_ms" not in r:
                raise SourceError(Loc(path, n, 1), "expected a JSON object with 't_ms' (a "
                                                   "trace written by simulate --trace)")
            rows.append(r)
    if not rows:
        raise SourceError(Loc(path, 1, 1), "empty trace")
    return rows


def all_keys(rows: list[dict[str, Any]]) -> list[str]:
    keys: dict[str, None] = {}
    for r in rows:
        for k in r:
            keys.setdefault(k, None)
    return [k for k in keys if k not in ("cycle", "t_ms")]


def instances(keys: list[str]) -> list[str]:
    """Instances of the trace: every instance has the chart flag SFCInit."""
    return [k[:-len(".SFCInit")] for k in keys if k.endswith(".SFCInit")]


_PREFIX = {"inputs": re.compile(r"i[A-Z0-9_]"), "outputs": re.compile(r"o[A-Z0-9_]"),
           "memory": re.compile(r"s[A-Z0-9_]")}


def default_signals(keys: list[str]) -> list[tuple[str, list[str]]]:
    """[(group title, keys)]: per instance, inputs, steps, outputs, memory."""
    groups: list[tuple[str, list[str]]] = []
    for inst in instances(keys):
        mine = [k for k in keys if k.startswith(inst + ".")]
        local = {k: k[len(inst) + 1:] for k in mine}
        steps = [k for k in mine if local[k].endswith(".X") and local[k].count(".") == 1]
        sel = {
            "inputs": [k for k in mine if _PREFIX["inputs"].match(local[k]) and "." not in
                       local[k]],
            "steps": steps,
            "outputs": [k for k in mine if _PREFIX["outputs"].match(local[k]) and "." not in
                        local[k]],
            "memory": [k for k in mine if _PREFIX["memory"].match(local[k]) and "." not in
                       local[k]],
        }
        if not any(sel.values()):  # no seed prefixes: everything but flags and times
            sel = {"signals": [k for k in mine if not local[k].startswith("SFC")
                               and not local[k].endswith(".T_ms")]}
        for title, ks in sel.items():
            if ks:
                groups.append((f"{inst}: {title}", ks))
    if not groups:  # not a plant trace: every key
        groups.append(("signals", keys))
    return groups


def plant_signals(plant: str, keys: list[str]) -> tuple[list[tuple[str, list[str]]],
                                                         dict[str, str]]:
    """Groups and kinds from the plant file's charts (exact, whatever the names)."""
    from runtime.language.model import VarKind
    from runtime.language.plantfile import load_plant

    p = load_plant(plant)
    groups: list[tuple[str, list[str]]] = []
    kinds: dict[str, str] = {}
    for name, inst in p.instances.items():
        g = inst.grafcet
        for v in g.variables.values():
            kinds[f"{name}.{v.name}"] = ("bool" if v.type.value == "bool" else
                                         "text" if v.type.value == "string" else "number")
        for s in g.steps:
            kinds[f"{name}.{s}.X"] = "bool"
        sel = {
            "inputs": [f"{name}.{v.name}" for v in g.inputs],
            # every step, macro-steps included (their .X is true while the expansion runs)
            "steps": [f"{name}.{s}.X" for s in g.steps],
            "outputs": [f"{name}.{v.name}" for v in g.outputs],
            "memory": [f"{name}.{v.name}" for v in g.variables.values()
                       if v.kind is VarKind.MEMORY],
        }
        for title, ks in sel.items():
            ks = [k for k in ks if k in keys]
            if ks:
                groups.append((f"{name}: {title}", ks))
    return groups, kinds


def select(keys: list[str], patterns: list[str]) -> list[str]:
    out: list[str] = []
    for p in patterns:
        if p in keys:
            found = [p]
        elif any(c in p for c in "*?["):
            found = [k for k in keys if fnmatch.fnmatchcase(k, p)]
        else:
            found = [k for k in keys if k.endswith("." + p)]
        if not found:
            near = [k for k in keys if p.lower() in k.lower()][:5]
            hint = f" (similar: {', '.join(near)})" if near else ""
            raise SourceError(Loc("--signals", 1, 1), f"no signal '{p}' in the trace{hint}")
        out += [k for k in found if k not in out]
    return out


@dataclass
class Series:
    key: str
    kind: str  # bool | number | text
    changes: list[tuple[float, Any]]  # (t_ms, value) at each change


def series(rows: list[dict[str, Any]], key: str, kind: str | None = None) -> Series:
    values = [r.get(key) for r in rows]
    present = [v for v in values if v is not None]
    if kind is not None:
        pass
    elif all(isinstance(v, bool) or v in (0, 1) for v in present):
        kind = "bool"
    elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        kind = "number"
    else:
        kind = "text"
    changes: list[tuple[float, Any]] = []
    last: Any = object()
    for r, v in zip(rows, values, strict=True):
        if kind == "bool" and v is not None:
            v = 1 if v else 0
        if v != last:
            changes.append((float(r["t_ms"]), v))
            last = v
    return Series(key, kind, changes)


def _label(group: str, key: str) -> str:
    """A key as written beside its row: without the instance when the heading names it."""
    inst = group.split(":", 1)[0] if ":" in group else ""
    if inst and key.startswith(inst + "."):
        return key[len(inst) + 1:]
    return key


def _nice_step(span: float, target: int = 10) -> float:
    raw = span / max(1, target)
    if raw <= 0:
        return 1.0
    mag = 10.0 ** math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if raw <= m * mag:
            return m * mag
    return 10 * mag


def _fmt_t(ms: float) -> str:
    if ms == 0:
        return "0"
    if abs(ms) >= 1000:
        return f"{ms / 1000:g} s"
    return f"{ms:g} ms"


def _fmt_v(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def chronogram_svg(rows: list[dict[str, Any]], groups: list[tuple[str, list[str]]],
                   width: float = 1000.0, cursor: int | None = None, title: str = "",
                   kinds: dict[str, str] | None = None) -> str:
    t0 = float(rows[0]["t_ms"])
    t_last = float(rows[-1]["t_ms"])
    dt = (t_last - float(rows[-2]["t_ms"])) if len(rows) > 1 else 1.0
    t_end = t_last + (dt if dt > 0 else 1.0)
    shown = {k: _label(gtitle, k) for gtitle, ks in groups for k in ks}
    label_w = max([len(v) * CHAR_W for v in shown.values()] + [80.0]) + 16
    left, plot_w = label_w + 10, max(200.0, width - label_w - 30)

    def x(t: float) -> float:
        return left + (t - t0) / (t_end - t0) * plot_w

    svg = Svg()
    y = 40.0 if title else 16.0
    y_grid = y
    if title:
        svg.add(f'<text x="10" y="22" font-size="14" font-weight="bold">{esc(title)}'
                     f'</text>')
    grid_at = len(svg.parts)  # the grid goes under the signals
    for gtitle, keys in groups:
        y += 6
        svg.add(f'<text x="10" y="{y + 10:.1f}" font-size="11" font-weight="bold" '
                     f'fill="#555">{esc(gtitle)}</text>')
        y += 16
        for k in keys:
            s = series(rows, k, (kinds or {}).get(k))
            top, bot = y, y + ROW_H
            mid = (top + bot) / 2
            svg.add(f'<text x="10" y="{mid + 4:.1f}" font-size="11" class="signal" '
                         f'data-key="{esc_attr(k)}">{esc(shown[k])}</text>')
            svg.add(f'<line x1="{left:.1f}" y1="{bot:.1f}" x2="{left + plot_w:.1f}" '
                         f'y2="{bot:.1f}" stroke="#eee"/>')
            spans = [(t, s.changes[i + 1][0] if i + 1 < len(s.changes) else t_end, v)
                     for i, (t, v) in enumerate(s.changes)]
            if s.kind == "bool":
                fill = STEP_FILL if k.endswith(".X") else HIGH_FILL
                pts: list[str] = []
                for a, b, v in spans:
                    if v is None:
                        continue
                    yy = top + 2 if v else bot
                    pts += [f"{x(a):.1f},{yy:.1f}", f"{x(b):.1f},{yy:.1f}"]
                    if v:
                        svg.add(f'<rect x="{x(a):.1f}" y="{top + 2:.1f}" '
                                     f'width="{max(0.5, x(b) - x(a)):.1f}" '
                                     f'height="{ROW_H - 2:.1f}" fill="{fill}"/>')
                svg.add(f'<polyline points="{" ".join(pts)}" fill="none" stroke="black" '
                             f'stroke-width="1.2"/>')
            else:
                for a, b, v in spans:
                    if v is None:
                        continue
                    xa, xb = x(a), x(b)
                    e = min(3.0, (xb - xa) / 2)
                    svg.add(f'<polygon points="{xa:.1f},{mid:.1f} {xa + e:.1f},'
                                 f'{top + 1:.1f} {xb - e:.1f},{top + 1:.1f} {xb:.1f},'
                                 f'{mid:.1f} {xb - e:.1f},{bot:.1f} {xa + e:.1f},{bot:.1f}" '
                                 f'fill="{BAND_FILL}" stroke="black" stroke-width="1"/>')
                    text = _fmt_v(v)
                    if len(text) * CHAR_W < xb - xa - 6:
                        svg.add(f'<text x="{(xa + xb) / 2:.1f}" y="{mid + 4:.1f}" '
                                     f'font-size="11" text-anchor="middle">{esc(text)}'
                                     f'</text>')
            y = bot + ROW_GAP
    # time axis
    y += 4
    svg.add(f'<line x1="{left:.1f}" y1="{y:.1f}" x2="{left + plot_w:.1f}" y2="{y:.1f}" '
                 f'stroke="black"/>')
    step = _nice_step(t_end - t0)
    t = math.ceil(t0 / step) * step
    while t <= t_end + 1e-9:
        xx = x(t)
        svg.add(f'<line x1="{xx:.1f}" y1="{y:.1f}" x2="{xx:.1f}" y2="{y + 5:.1f}" '
                     f'stroke="black"/>')
        svg.insert(grid_at, f'<line x1="{xx:.1f}" y1="{y_grid:.1f}" x2="{xx:.1f}" '
                              f'y2="{y:.1f}" stroke="#ddd" stroke-dasharray="2,3"/>')
        svg.add(f'<text x="{xx:.1f}" y="{y + 17:.1f}" font-size="10" '
                     f'text-anchor="middle">{esc(_fmt_t(t))}</text>')
        t += step
    if cursor is not None:
        row = next((r for r in rows if r.get("cycle") == cursor), None)
        if row is not None:
            xx = x(float(row["t_ms"]))
            svg.add(f'<line x1="{xx:.1f}" y1="16" x2="{xx:.1f}" y2="{y:.1f}" '
                         f'stroke="red" stroke-width="1.2" class="cursor"/>')
            svg.add(f'<text x="{xx + 3:.1f}" y="{y - 3:.1f}" font-size="10" fill="red">'
                         f'cycle {cursor}</text>')
    height = y + 30
    total_w = left + plot_w + 20
    return svg.document(total_w, height, 0.0, ['<rect width="100%" height="100%" fill="white"/>'])


def parse_ms(text: str, what: str) -> float:
    """``2s``, ``1500ms``, ``1m30s`` or a plain number of milliseconds -> ms."""
    t = strip_time_prefix(text.strip())
    try:
        return float(t)
    except ValueError:
        pass
    ns = parse_literal(t)
    if ns is None:
        raise SourceError(Loc(what, 1, 1), f"expected a time (2s, 1500ms or a number of ms), "
                                           f"found '{text}'")
    return ns / 1e6


def window(rows: list[dict[str, Any]], start: float | None,
           end: float | None) -> list[dict[str, Any]]:
    """The scans with ``start <= t_ms <= end`` (ms; None: no bound)."""
    lo = -math.inf if start is None else start
    hi = math.inf if end is None else end
    if lo > hi:
        raise SourceError(Loc("--from", 1, 1), f"--from {start:g} ms is after --to {end:g} ms")
    out = [r for r in rows if lo <= float(r["t_ms"]) <= hi]
    if not out:
        raise SourceError(Loc("--from", 1, 1), f"no scan between {lo:g} and {hi:g} ms (the "
                                               f"trace runs from {rows[0]['t_ms']} to "
                                               f"{rows[-1]['t_ms']} ms)")
    return out


def regroup(keys: list[str], groups: list[tuple[str, list[str]]]) -> list[tuple[str, list[str]]]:
    """``keys`` in the order given, headed by the group each belongs to (a new heading
    where the group changes)."""
    group_of = {k: title for title, ks in groups for k in ks}
    out: list[tuple[str, list[str]]] = []
    for k in keys:
        title = group_of.get(k, "")
        if out and out[-1][0] == title:
            out[-1][1].append(k)
        else:
            out.append((title, [k]))
    return out


def chronogram(trace: str, out: str, signals: list[str] | None = None,
               width: float = 1000.0, cycle: int | None = None,
               plant: str | None = None, start: float | None = None,
               end: float | None = None, title: str | None = None) -> int:
    """Write the SVG; returns the number of signals drawn. ``start``/``end``: the time
    window in ms."""
    rows = load_trace(trace)
    keys = all_keys(rows)
    kinds: dict[str, str] = {}
    groups: list[tuple[str, list[str]]] = []
    if plant is not None:
        groups, kinds = plant_signals(plant, keys)
    if not groups:
        groups = default_signals(keys)
    if signals:
        groups = regroup(select(keys, signals), groups)
    rows = window(rows, start, end)
    if title is None:
        title = (f"{os.path.basename(trace)} — {len(rows)} scans, "
                 f"{_fmt_t(float(rows[0]['t_ms']))} to {_fmt_t(float(rows[-1]['t_ms']))}")
    svg = chronogram_svg(rows, groups, width, cycle, title, kinds)
    with open(out, "w", encoding="utf-8") as f:
        f.write(svg)
    return sum(len(ks) for _, ks in groups)


def cmd_chronogram(args: argparse.Namespace) -> int:
    try:
        start = None if args.start is None else parse_ms(args.start, "--from")
        end = None if args.end is None else parse_ms(args.end, "--to")
        n = chronogram(args.trace, args.output, args.signals, args.width, args.cycle,
                       args.plant, start, end, args.title)
    except SourceError as exc:
        sys.stderr.write(f"{exc}\n")
        return 2
    except OSError as exc:
        sys.stderr.write(f"softplc chronogram: error: {exc}\n")
        return 2
    sys.stderr.write(f"{args.output}: written ({n} signals)\n")
    return 0


def register(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    c = sub.add_parser("chronogram", help="draw a trace as a timing diagram (SVG)",
                       description="Draw a trace (simulate --trace) as a timing diagram: "
                                   "bools as square waves, numbers as value bands.")
    c.add_argument("trace", metavar="TRACE.jsonl")
    c.add_argument("-o", "--output", required=True, metavar="OUT.svg")
    c.add_argument("--signals", nargs="+", metavar="SIGNAL",
                   help="keys, glob patterns or names without the instance (default: "
                        "inputs, steps, outputs and memory of every instance)")
    c.add_argument("--cycle", type=int, metavar="K", help="draw a cursor at scan K")
    c.add_argument("--plant", metavar="PLANT.yaml",
                   help="the plant that wrote the trace: exact groups and types (a counter "
                        "that only reached 1 is drawn as a number, not a square wave)")
    c.add_argument("--from", dest="start", metavar="TIME",
                   help="start of the time window (2s, 1500ms, or ms; default: the start)")
    c.add_argument("--to", dest="end", metavar="TIME",
                   help="end of the time window (default: the end of the trace)")
    c.add_argument("--title", help="title above the diagram (default: the trace's name and "
                                   "window)")
    c.add_argument("--width", type=float, default=1000.0, help="width in px (default 1000)")
    c.set_defaults(func=cmd_chronogram)
