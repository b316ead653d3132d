"""An SFC body as steps and transitions: every link followed by its ``refLocalId`` from the
element that consumes it back to the one that produces it, so that a file's elements may
come in any order.

A transition's source steps are found going up its input (through a selection divergence
or a simultaneous convergence), its target steps going down to every element whose input
names it (through a simultaneous divergence or a selection convergence; a jump step stands
for the step it names). Each link is checked against the schema's meaning (a step's input
comes from a transition or a convergence, a transition's from a step or a divergence ...);
a reference to no element, a cycle of references that meets no step or transition, a jump
to no step are errors at their place.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from runtime.errors import SourceError
from runtime.plcopen.interface import Note, softplc_data
from runtime.plcopen.schema import PLCOPEN_NS
from runtime.plcopen.vendor import codesys_attributes
from runtime.plcopen.xmltree import Element

#: element -> its part in the flow of the chart
KINDS = {"step": "step", "macroStep": "step", "jumpStep": "jump", "transition": "transition",
         "selectionDivergence": "sdiv", "selectionConvergence": "sconv",
         "simultaneousDivergence": "pdiv", "simultaneousConvergence": "pconv",
         "actionBlock": "actions"}
#: FBD and LD elements: a transition's condition may be drawn with them
NETWORK = frozenset({"inVariable", "outVariable", "inOutVariable", "contact", "coil",
                     "leftPowerRail", "rightPowerRail", "block", "connector", "continuation",
                     "label", "jump", "return", "vendorElement"})
#: drawing annotations: no behaviour, their text left out with a note
ANNOTATIONS = frozenset({"comment", "error"})
#: consumer kind -> the kinds its input may come from
FEEDS = {"step": {"transition", "sconv", "pdiv"}, "jump": {"transition", "sconv", "pdiv"},
         "transition": {"step", "sdiv", "pconv"}, "sdiv": {"step", "pconv"},
         "sconv": {"transition", "pdiv"}, "pdiv": {"transition", "sconv"},
         "pconv": {"step", "sdiv"}, "actions": {"step"}}
_WORDS = {"step": "a step", "jump": "a jump step", "transition": "a transition",
          "sdiv": "a selection divergence", "sconv": "a selection convergence",
          "pdiv": "a simultaneous divergence", "pconv": "a simultaneous convergence",
          "actions": "an action block", "network": "an FBD/LD element"}


@dataclass
class GStep:
    id: int
    e: Element
    name: str
    macro: Level | None = None


@dataclass
class GTransition:
    id: int
    e: Element
    sources: list[str]
    targets: list[str]


@dataclass
class Level:
    """One body: the chart's, or a macro-step's expansion."""

    sfc: Element
    elements: dict[int, Element]
    kind: dict[int, str]
    steps: dict[str, GStep] = field(default_factory=dict)  # by name, in localId order
    transitions: list[GTransition] = field(default_factory=list)  # in localId order
    blocks: dict[str, list[Element]] = field(default_factory=dict)  # step -> action blocks
    comments: list[Element] = field(default_factory=list)  # the body's comments
    names: dict[int, str] = field(default_factory=dict)  # step localId -> name
    #: element -> (its input's producer, the connection element), every input of the flow
    inputs: dict[int, list[tuple[int, Element]]] = field(default_factory=dict)
    consumers: dict[int, list[int]] = field(default_factory=dict)

    def element(self, ref: int) -> Element:
        return self.elements[ref]


def local_id(e: Element) -> int:
    raw = e.get("localId")
    if raw is None or not raw.strip().isdigit():
        found = "none" if raw is None else f"'{raw}'"
        raise SourceError(e.loc, f"expected a localId (an unsigned integer) on <{e.tag}>, "
                                 f"found {found}")
    return int(raw)


def connections(point: Element, elements: Mapping[int, Element]) -> list[tuple[int, Element]]:
    """(producer, connection element) of each connection of a connection point; a
    reference to no element of the body (``elements``, by localId) is an error at the
    connection."""
    out = []
    for c in point.findall("connection", PLCOPEN_NS):
        raw = c.get("refLocalId")
        if raw is None or not raw.strip().isdigit():
            raise SourceError(c.loc, f"expected a refLocalId (an unsigned integer), found "
                                     f"{'none' if raw is None else repr(raw)}")
        ref = int(raw)
        if ref not in elements:
            raise SourceError(c.loc, f"dangling reference: refLocalId {ref} names no element "
                                     "of this SFC body")
        out.append((ref, c))
    return out


def read_level(sfc: Element, note: Note) -> Level:
    """The steps and transitions of an ``SFC`` body (macro-steps' bodies read in turn)."""
    level = Level(sfc, {}, {})
    for e in sfc.children:
        if e.ns != PLCOPEN_NS:
            continue
        if e.tag not in KINDS and e.tag not in NETWORK and e.tag not in ANNOTATIONS:
            raise SourceError(e.loc, f"unknown element <{e.tag}> in an SFC body")
        i = local_id(e)
        if i in level.elements:
            raise SourceError(e.loc, f"localId {i} is given twice in this SFC body (first "
                                     f"at line {level.elements[i].loc.line})")
        level.elements[i] = e
        level.kind[i] = KINDS.get(e.tag, "network" if e.tag in NETWORK else "annotation")
    for i in sorted(level.elements):
        e, kind = level.elements[i], level.kind[i]
        if kind == "annotation" and e.tag == "comment":
            level.comments.append(e)
            continue
        if kind == "annotation":
            note(e.loc, f"localId {i}: {e.tag} left out (an editor's error marker)")
            continue
        if kind == "network":
            continue
        ins: list[tuple[int, Element]] = []
        for point in e.findall("connectionPointIn", PLCOPEN_NS):
            ins += connections(point, level.elements)
        for ref, conn in ins:
            if level.kind[ref] not in FEEDS[kind]:
                raise SourceError(conn.loc, f"localId {i}: {_WORDS[kind]}'s input connects to "
                                  f"{_WORDS[level.kind[ref]]} (localId {ref}): expected "
                                  f"{' or '.join(_WORDS[k] for k in sorted(FEEDS[kind]))}")
            level.consumers.setdefault(ref, []).append(i)
        if len(ins) > 1 and kind in ("transition", "sdiv", "pdiv", "actions"):
            raise SourceError(ins[1][1].loc, f"localId {i}: {_WORDS[kind]} has {len(ins)} "
                              "connections into its input: expected one (join several with a "
                              "convergence)")
        level.inputs[i] = ins
    _no_cycles(level)
    for i in sorted(level.elements):
        e = level.elements[i]
        if level.kind[i] == "step":
            _step(level, i, e, note)
    for i in sorted(level.elements):
        if level.kind[i] == "transition":
            level.transitions.append(_transition(level, i))
        elif level.kind[i] == "actions":
            _action_block(level, i, note)
    return level


def _step(level: Level, i: int, e: Element, note: Note) -> None:
    name = e.get("name") or ""
    if e.tag == "macroStep" and not name:
        name = f"M{i}"
        note(e.loc, f"localId {i}: macro-step without a name: named {name}")
    codesys = codesys_attributes(e).get("name", "")
    if codesys:
        name = codesys
    if not name:
        raise SourceError(e.loc, f"localId {i}: a step needs a name")
    if name in level.steps:
        first = level.steps[name].e.loc.line
        raise SourceError(e.loc, f"step name '{name}' is given twice (first at line {first})")
    st = GStep(i, e, name)
    if e.get("negated") == "true":
        note(e.loc, f"localId {i}: negated step '{name}': 'negated' left out (it has no "
                    "meaning for a step)")
    if e.tag == "macroStep":
        body = e.find("body", PLCOPEN_NS)
        inner = body.find("SFC", PLCOPEN_NS) if body is not None else None
        if inner is None:
            raise SourceError(e.loc, f"localId {i}: macro-step '{name}' has no SFC body: "
                                     "expected its expansion in <body><SFC>")
        st.macro = read_level(inner, note)
    level.steps[name] = st
    level.names[i] = name


def _no_cycles(level: Level) -> None:
    """Links between divergences and convergences (or FBD/LD elements) that go round
    without meeting a step or a transition: an error at the element closing the cycle."""
    through = {i for i, k in level.kind.items() if k in ("sdiv", "sconv", "pdiv", "pconv")}
    state: dict[int, int] = {}
    for start in sorted(through):
        if start in state:
            continue
        path = [start]
        state[start] = 1
        stack = [iter([r for r, _ in level.inputs.get(start, [])])]
        while stack:
            ref = next(stack[-1], None)
            if ref is None:
                state[path.pop()] = 2
                stack.pop()
                continue
            if ref not in through:
                continue
            if state.get(ref) == 1:
                cycle = path[path.index(ref):] + [ref]
                raise SourceError(level.elements[path[-1]].loc, "cycle in refLocalId: "
                                  f"{' -> '.join(map(str, cycle))} (a divergence or a "
                                  "convergence must lead to a step or a transition)")
            if ref not in state:
                state[ref] = 1
                path.append(ref)
                stack.append(iter([r for r, _ in level.inputs.get(ref, [])]))


def _up(level: Level, ref: int) -> list[int]:
    """The steps a transition's input comes from, through divergences and convergences."""
    out: list[int] = []
    seen = {ref}
    stack = [ref]
    while stack:
        i = stack.pop()
        if level.kind[i] == "step":
            out.append(i)
            continue
        for r, _ in reversed(level.inputs.get(i, [])):
            if r not in seen:
                seen.add(r)
                stack.append(r)
    return out


def _down(level: Level, ref: int) -> list[str]:
    """The steps (names) below transition ``ref``, through divergences and convergences;
    a jump step stands for the step it names."""
    out: list[str] = []
    seen = {ref}
    stack = [ref]
    while stack:
        i = stack.pop()
        for c in reversed(level.consumers.get(i, [])):
            if c in seen:
                continue
            seen.add(c)
            kind = level.kind[c]
            if kind == "step":
                out.append(level.names[c])
            elif kind == "jump":
                out.append(_jump_target(level, c))
            elif kind in ("pdiv", "sconv"):
                stack.append(c)
    return out


def _jump_target(level: Level, i: int) -> str:
    e = level.elements[i]
    target = e.get("targetName") or ""
    if target in level.steps:
        return target
    folded = [n for n in level.steps if n.lower() == target.lower()]
    if len(folded) == 1:
        return folded[0]
    raise SourceError(e.loc, f"localId {i}: jump step to '{target}': no step of that name in "
                             f"this SFC body (steps: {', '.join(level.steps) or 'none'})")


def _transition(level: Level, i: int) -> GTransition:
    e = level.elements[i]
    sources: list[str] = []
    for r, _ in level.inputs.get(i, []):
        sources += [level.names[s] for s in _up(level, r)]
    targets = _down(level, i)
    sp = softplc_data(e, "transition")
    if not sources and (sp is None or sp.get("source") != "true"):
        raise SourceError(e.loc, f"localId {i}: transition with no step above it: expected "
                                 "its input connected to a step (or a divergence)")
    if not targets and (sp is None or sp.get("sink") != "true"):
        raise SourceError(e.loc, f"localId {i}: transition that leads to no step: expected a "
                                 "step, a jump step or a divergence connected below it")
    return GTransition(i, e, _written(level, sources, sp, "sources"),
                       _written(level, targets, sp, "targets"))


def _written(level: Level, names: list[str], sp: Element | None, key: str) -> list[str]:
    """The steps of a transition in the order softplc wrote them (its data), else left to
    right, top to bottom (``from: [A, B]``: the order does not change what the chart does)."""
    found = list(dict.fromkeys(names))
    kept = (sp.get(key) or "").split() if sp is not None else []
    if sorted(kept) == sorted(found):
        return kept
    return sorted(found, key=lambda n: (*position(level.steps[n].e), n))


def _action_block(level: Level, i: int, note: Note) -> None:
    e = level.elements[i]
    ins = level.inputs.get(i, [])
    if not ins:
        note(e.loc, f"localId {i}: action block connected to no step left out")
        return
    step = level.names[ins[0][0]]
    if level.steps[step].macro is not None:
        note(e.loc, f"localId {i}: actions of macro-step '{step}' left out (a macro-step "
                    "carries no actions of its own: put them on a step of its expansion)")
        return
    level.blocks.setdefault(step, []).append(e)


def position(e: Element) -> tuple[float, float]:
    """(x, y) of an element's ``position``, (0, 0) without one."""
    p = e.find("position", PLCOPEN_NS)
    if p is None:
        return 0.0, 0.0
    try:
        return float(p.get("x") or 0), float(p.get("y") or 0)
    except ValueError:
        raise SourceError(p.loc, "expected a position with numbers x and y") from None


