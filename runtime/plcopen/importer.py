"""``softplc import``: each SFC POU of a PLCopen file as a chart of the language.

The POU becomes a chart document (what a grafcet YAML file holds) whose every key, value and
character of text keeps its place in the XML file; the language's own loader then checks
it, so a fault in an ST condition is reported at its line and column in the XML file.
What the file holds that a chart cannot carry is left out with one note each, naming the
element's localId (docs/plcopen.md lists every element and what becomes of it). When the
file holds softplc's own additional data (it was exported by ``softplc export``), the texts
as written, the order and what PLCopen has no element for come back from it, unless the
element was changed in an editor since (its ST text or native form differs from the one
exported).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from drivers.durations import format_ns, parse_literal, strip_time_prefix
from runtime.errors import Loc, SourceError
from runtime.language.grafcetfile import GrafcetLoader
from runtime.language.lexer import KEYWORDS, Lexer, is_name
from runtime.language.model import Grafcet
from runtime.language.signatures import FB_MEMBERS, TIMER_METHODS
from runtime.language.typecheck import FLAGS_BOOL, FLAGS_STRING, SYSTEM_BOOL
from runtime.language.yamlsrc import YList, YMap, YStr
from runtime.plcopen.interface import Interface, read_interface, softplc_data
from runtime.plcopen.network import Network
from runtime.plcopen.order import order
from runtime.plcopen.schema import PLCOPEN_NS, QUALIFIERS, SOFTPLC_NS, TIMED
from runtime.plcopen.sfcgraph import GStep, GTransition, Level, position, read_level
from runtime.plcopen.texts import (
    compose,
    fingerprint,
    formatted,
    native_text,
    plain,
    spell_as_declared,
    sub,
)
from runtime.plcopen.vendor import codesys_attributes, codesys_objects, is_codesys
from runtime.plcopen.xmltree import Element, parse_xml


@dataclass(frozen=True)
class Note:
    """Something of the file the chart does not carry, or carries changed (``lost``), or a
    choice the importer made that the user should know of."""

    loc: Loc
    message: str
    lost: bool = True

    def __str__(self) -> str:
        return f"{self.loc}: {'warning' if self.lost else 'note'}: {self.message}"


@dataclass
class ImportedChart:
    """One SFC POU as a chart."""

    pou: str
    doc: YMap  # the chart document, places in the XML file
    grafcet: Grafcet  # as the language's loader reads the document
    interface: Interface
    instance: str  # the POU's instance in the file's configuration, else the POU's name
    cycle_ns: int | None  # the interval of the task that runs it, if any


@dataclass
class ImportResult:
    charts: list[ImportedChart] = field(default_factory=list)
    notes: list[Note] = field(default_factory=list)


def import_file(path: str, pou: str | None = None) -> ImportResult:
    """Every SFC POU of the PLCopen file at ``path`` (or the one named ``pou``) as a
    chart; SourceError at the place of the first fault."""
    root = parse_xml(path)
    if root.ns != PLCOPEN_NS or root.tag != "project":
        raise SourceError(root.loc, f"expected a PLCopen TC6 XML v2.01 project (<project "
                                    f"xmlns=\"{PLCOPEN_NS}\">), found <{root.tag}>"
                                    + (f" in namespace {root.ns}" if root.ns else ""))
    result = ImportResult()
    types = root.find("types", PLCOPEN_NS)
    pous = types.find("pous", PLCOPEN_NS) if types is not None else None
    all_pous = pous.findall("pou", PLCOPEN_NS) if pous is not None else []
    sfc_pous = [p for p in all_pous if _sfc_body(p) is not None]
    if pou is not None:
        named = [p for p in all_pous if p.get("name") == pou]
        if not named:
            raise SourceError(root.loc, f"no POU named '{pou}' in the file (POUs: "
                              f"{', '.join(p.get('name') or '?' for p in all_pous) or 'none'})")
        if _sfc_body(named[0]) is None:
            raise SourceError(named[0].loc, f"POU '{pou}' is not written in SFC")
        sfc_pous = named[:1]
    if not sfc_pous:
        raise SourceError(root.loc, "no POU written in SFC in the file (softplc imports SFC "
                                    "charts)")
    codesys = is_codesys(root)
    tasks = _tasks(root)
    for p in sfc_pous:
        name = p.get("name") or ""
        chart = _PouImporter(path, p, codesys, result.notes).run()
        instance, cycle = tasks.get(name, (name, None))
        g = GrafcetLoader(path, chart[0]).load()
        result.charts.append(ImportedChart(name, chart[0], g, chart[1], instance, cycle))
    return result


def _sfc_body(pou: Element) -> Element | None:
    for body in pou.findall("body", PLCOPEN_NS):
        sfc = body.find("SFC", PLCOPEN_NS)
        if sfc is not None:
            return sfc
    return None


def _tasks(root: Element) -> dict[str, tuple[str, int | None]]:
    """POU name -> (its instance's name, the interval of the task running it, ns)."""
    out: dict[str, tuple[str, int | None]] = {}
    instances = root.find("instances", PLCOPEN_NS)
    for holder in instances.iter() if instances is not None else []:
        if holder.tag not in ("task", "resource"):
            continue
        interval = (holder.get("interval") or "").strip() if holder.tag == "task" else ""
        cycle = parse_literal(strip_time_prefix(interval).replace("_", "")) or None
        for e in holder.findall("pouInstance", PLCOPEN_NS):
            name = e.get("name") or ""
            if is_name(name) and name.upper() not in KEYWORDS:
                out.setdefault(e.get("typeName") or "", (name, cycle))
    return out


# -- documents with places -------------------------------------------------------------------
def _map(loc: Loc) -> YMap:
    m = YMap()
    m.loc, m.key_locs, m.val_locs = loc, {}, {}
    return m


def _put(m: YMap, key: str, value: Any, loc: Loc) -> None:
    m[key] = value
    m.key_locs[key] = loc
    m.val_locs[key] = value.loc if isinstance(value, (YStr, YMap, YList)) else loc


def _list(loc: Loc, items: list[tuple[Any, Loc]]) -> YList:
    out = YList(v for v, _ in items)
    out.loc = loc
    out.locs = [v.loc if isinstance(v, (YStr, YMap, YList)) else at for v, at in items]
    return out


def _zero(typ: str) -> object:
    return {"bool": False, "int": 0, "real": 0.0, "time": 0}[typ]


# -- one POU ---------------------------------------------------------------------------------
class _PouImporter:
    def __init__(self, path: str, pou: Element, codesys: bool, notes: list[Note]) -> None:
        self.path, self.pou, self.codesys, self.notes = path, pou, codesys, notes
        self.name = pou.get("name") or ""
        self.actions = self._named(pou, "actions", "action")
        self.transitions = self._named(pou, "transitions", "transition")
        self.spelling: dict[str, str] = {}
        self.uses: dict[str, int] = {}  # POU transition name (lower case) -> references
        self.used_actions: set[str] = set()  # POU action names (lower case) steps use
        self.networks: dict[int, Network] = {}  # per level (id): its FBD/LD elements
        self.names_given: set[str] = set()  # transition names, unique in a chart

    def note(self, loc: Loc, message: str) -> None:
        self.notes.append(Note(loc, message))

    @staticmethod
    def _named(pou: Element, group: str, tag: str) -> dict[str, Element]:
        """POU actions or transitions by their name in lower case (IEC names ignore case)."""
        out: dict[str, Element] = {}
        g = pou.find(group, PLCOPEN_NS)
        for e in [*(g.findall(tag, PLCOPEN_NS) if g is not None else []),
                  *codesys_objects(pou, tag)]:
            out.setdefault((e.get("name") or "").lower(), e)
        return out

    def run(self) -> tuple[YMap, Interface]:
        pou = self.pou
        iface = read_interface(pou, self.note)
        sfc = _sfc_body(pou)
        assert sfc is not None
        level = read_level(sfc, self.note)
        self._spelling(iface, level)
        self._count_references(level)
        doc = _map(pou.loc)
        _put(doc, "grafcet", plain(self.name, pou.loc), pou.loc)
        docu = pou.find("documentation", PLCOPEN_NS)
        if docu is not None:
            _put(doc, "description", str(formatted(docu)), docu.loc)
        chart = softplc_data(pou, "chart")
        if chart is not None and chart.get("scan"):
            _put(doc, "scan", plain(chart.get("scan") or "", chart.loc), chart.loc)
        elif self.codesys:
            _put(doc, "scan", plain("codesys", pou.loc), pou.loc)
            self.notes.append(Note(pou.loc, f"POU '{self.name}' comes from CODESYS: "
                                   "imported with 'scan: codesys' (CODESYS's processing order, "
                                   "docs/semantics.md)", lost=False))
        self._variables(doc, iface)
        self._equations(doc, chart, "pre")
        steps, transitions = self._level(level, None)
        _put(doc, "steps", steps, sfc.loc)
        if transitions:
            _put(doc, "transitions", transitions, sfc.loc)
        self._equations(doc, chart, "post")
        self._used_transitions()
        return doc, iface

    @staticmethod
    def _equations(doc: YMap, chart: Element | None, part: str) -> None:
        """pre or post, from softplc's data (PLCopen has no element for them)."""
        texts = [(e.ystr(), e.loc) for e in chart.findall(part, SOFTPLC_NS)] if chart else []
        if texts:
            _put(doc, part, _list(texts[0][1], texts), texts[0][1])

    # -- names -----------------------------------------------------------------------------
    def _spelling(self, iface: Interface, level: Level) -> None:
        """Every name the chart's texts may use, by its lower case (IEC 61131-3 names
        ignore case); names that two spellings share are left as written."""
        names = [*iface.names(), *FLAGS_BOOL, *FLAGS_STRING, *SYSTEM_BOOL, *TIMER_METHODS,
                 *(m for members in FB_MEMBERS.values() for m in members)]
        stack = [level]
        while stack:
            lv = stack.pop()
            names += list(lv.steps)
            stack += [s.macro for s in lv.steps.values() if s.macro is not None]
        seen: dict[str, set[str]] = {}
        for n in names:
            seen.setdefault(n.lower(), set()).add(n)
        self.spelling = {k: next(iter(v)) for k, v in seen.items() if len(v) == 1}

    def _text(self, text: YStr) -> YStr:
        return spell_as_declared(text, self.spelling)

    # -- variables --------------------------------------------------------------------------
    def _variables(self, doc: YMap, iface: Interface) -> None:
        for key, vs in (("inputs", iface.inputs), ("outputs", iface.outputs)):
            items: list[tuple[Any, Loc]] = []
            for v in vs:
                if v.type == "bool":
                    items.append((plain(v.name, v.loc), v.loc))
                else:
                    m = _map(v.loc)
                    _put(m, v.name, plain(v.type, v.loc), v.loc)
                    items.append((m, v.loc))
            if items:
                _put(doc, key, _list(items[0][1], items), items[0][1])
        if iface.memory:
            mem = _map(iface.memory[0][0].loc)
            for v, retained in iface.memory:
                init = v.init if v.init is not None else _zero(v.type)
                value: Any = plain(format_ns(int(init)), v.loc) if v.type == "time" else init  # type: ignore[call-overload]
                if retained or v.renamed_from:
                    spec = _map(v.loc)
                    _put(spec, "init", value, v.loc)
                    if retained:
                        _put(spec, "retain", True, v.loc)
                    if v.renamed_from:
                        _put(spec, "renamed_from", plain(v.renamed_from, v.loc), v.loc)
                    value = spec
                _put(mem, v.name, value, v.loc)
            _put(doc, "memory", mem, mem.loc)
        if iface.timers:
            _put(doc, "timers", _list(iface.timers[0][1], [(plain(n, at), at)
                                                           for n, at in iface.timers]),
                 iface.timers[0][1])
        if iface.blocks:
            blocks = _map(iface.blocks[0][2])
            for name, kind, at in iface.blocks:
                _put(blocks, name, plain(kind, at), at)
            _put(doc, "blocks", blocks, blocks.loc)

    # -- steps and transitions ----------------------------------------------------------------
    def _network(self, level: Level) -> Network:
        """The FBD/LD elements of a level's body (one reader per body: it notes what the
        conditions use)."""
        net = self.networks.get(id(level))
        if net is None:
            net = self.networks[id(level)] = Network(level.sfc)
        return net

    def _unused_network(self, level: Level) -> None:
        used = self.networks[id(level)].used if id(level) in self.networks else set()
        for i, kind in sorted(level.kind.items()):
            if kind == "network" and i not in used:
                e = level.elements[i]
                self.note(e.loc, f"localId {i}: {e.tag} left out: it is part of no "
                                 "transition's condition")

    def _level(self, level: Level, macro: GStep | None) -> tuple[YMap, YList]:
        initial = {n: self._initial(s) for n, s in level.steps.items()}
        names, transitions = order(level, lambda n: initial[n])
        entry = exit_ = None
        if macro is not None:
            entry, exit_ = self._ends(level, macro)
        steps = _map(level.steps[names[0]].e.loc if names else Loc(self.path, 1, 1))
        for n in names:
            st = level.steps[n]
            _put(steps, n, self._step(level, st, initial[n], n == entry, n == exit_),
                 st.e.loc)
        items = [(self._transition(level, t), t.e.loc) for t in transitions]
        trans = _list(items[0][1] if items else steps.loc, items)
        self._unused_network(level)
        return steps, trans

    def _initial(self, st: GStep) -> bool:
        sp = softplc_data(st.e, "step")
        if st.e.tag == "macroStep":
            return sp is not None and sp.get("initial") == "true"
        vendor = codesys_attributes(st.e).get("initial")
        if vendor:
            return vendor.upper() == "TRUE"
        return st.e.get("initialStep") == "true"

    def _ends(self, level: Level, macro: GStep) -> tuple[str, str]:
        """The entry and exit steps of a macro-step's expansion: as softplc marked them,
        else the one step no transition leads to and the one no transition leaves."""
        found = []
        for key in ("entry", "exit"):
            marked = [n for n, s in level.steps.items()
                      if (sp := softplc_data(s.e, "step")) is not None and sp.get(key) == "true"]
            if not marked:
                linked = {n for t in level.transitions
                          for n in (t.targets if key == "entry" else t.sources)}
                marked = [n for n in level.steps if n not in linked]
            if len(marked) != 1:
                what = ("no transition leads to" if key == "entry" else
                        "no transition leaves")
                raise SourceError(macro.e.loc, f"localId {macro.id}: cannot tell the {key} step "
                                  f"of macro-step '{macro.name}': expected one step that "
                                  f"{what}, found {len(marked)}"
                                  + (f" ({', '.join(marked)})" if marked else ""))
            found.append(marked[0])
        return found[0], found[1]

    def _step(self, level: Level, st: GStep, initial: bool, entry: bool, exit_: bool) -> YMap:
        e = st.e
        spec = _map(e.loc)
        sp = softplc_data(e, "step")
        vendor = codesys_attributes(e)
        if initial:
            _put(spec, "initial", True, e.loc)
        for flag, on in (("entry", entry), ("exit", exit_)):
            if on:
                _put(spec, flag, True, e.loc)
        for key in ("min", "max"):
            raw = sp.get(key) if sp is not None else None
            if raw is None and vendor.get(key):
                ns = parse_literal(strip_time_prefix(vendor[key].strip()).replace("_", ""))
                if ns is None:
                    raise SourceError(e.loc, f"localId {st.id}: CODESYS {key} time "
                                             f"'{vendor[key]}' is no time literal")
                raw = format_ns(ns) if ns else None
            if raw is not None:
                _put(spec, key, plain(raw, e.loc), e.loc)
        if sp is not None and sp.get("renamed_from"):
            _put(spec, "renamed_from", plain(sp.get("renamed_from") or "", sp.loc), sp.loc)
        docu = e.find("documentation", PLCOPEN_NS)
        text = str(formatted(docu)) if docu is not None else vendor.get("comment", "")
        if text:
            _put(spec, "description", text, docu.loc if docu is not None else e.loc)
        if st.macro is not None:
            steps, trans = self._level(st.macro, st)
            m = _map(e.loc)
            _put(m, "steps", steps, steps.loc)
            if trans:
                _put(m, "transitions", trans, trans.loc)
            _put(spec, "macro", m, e.loc)
            return spec
        actions = self._actions(level, st)
        if actions:
            _put(spec, "actions", _list(actions[0][1], actions), actions[0][1])
        return spec

    def _transition(self, level: Level, t: GTransition) -> YMap:
        e = t.e
        spec = _map(e.loc)
        for key, names in (("from", t.sources), ("to", t.targets)):
            if len(names) == 1:
                _put(spec, key, plain(names[0], e.loc), e.loc)
            else:
                _put(spec, key, _list(e.loc, [(plain(n, e.loc), e.loc) for n in names]), e.loc)
        _put(spec, "when", self._condition(level, t), e.loc)
        name = self._transition_name(t)
        if name and name in self.names_given:
            self.note(e.loc, f"localId {t.id}: transition name '{name}' left out: another "
                             "transition has it (names are unique in a chart)")
        elif name:
            self.names_given.add(name)
            _put(spec, "name", name, e.loc)
        docu = e.find("documentation", PLCOPEN_NS)
        if docu is not None and str(formatted(docu)):
            _put(spec, "description", str(formatted(docu)), docu.loc)
        return spec

    def _transition_name(self, t: GTransition) -> str:
        sp = softplc_data(t.e, "transition")
        if sp is not None and sp.get("name"):
            return sp.get("name") or ""
        cond = t.e.find("condition", PLCOPEN_NS)
        if cond is None:
            return ""
        inline = cond.find("inline", PLCOPEN_NS)
        if inline is not None:
            return (inline.get("name") or "").strip()
        ref = cond.find("reference", PLCOPEN_NS)
        if ref is not None:
            key = (ref.get("name") or "").lower()
            if key in self.transitions and self.uses.get(key) == 1:
                return self.transitions[key].get("name") or ""
        return ""

    def _count_references(self, level: Level) -> None:
        """How many transitions of the chart (macro-steps' expansions included) name each
        POU transition: its name becomes a transition's name when one only does."""
        for t in level.transitions:
            cond = t.e.find("condition", PLCOPEN_NS)
            ref = cond.find("reference", PLCOPEN_NS) if cond is not None else None
            if ref is not None:
                key = (ref.get("name") or "").lower()
                self.uses[key] = self.uses.get(key, 0) + 1
        for st in level.steps.values():
            if st.macro is not None:
                self._count_references(st.macro)

    def _used_transitions(self) -> None:
        for key, e in self.transitions.items():
            if key not in self.uses:
                self.note(e.loc, f"transition '{e.get('name')}' of the POU left out: no "
                                 "transition of the chart refers to it")
        for key, e in self.actions.items():
            if key not in self.used_actions:
                self.note(e.loc, f"action '{e.get('name')}' of the POU left out: no step "
                                 "refers to it")

    # -- conditions ---------------------------------------------------------------------------
    def _condition(self, level: Level, t: GTransition) -> YStr:
        e = t.e
        cond = e.find("condition", PLCOPEN_NS)
        if cond is None:
            raise SourceError(e.loc, f"localId {t.id}: transition without a condition")
        inline = cond.find("inline", PLCOPEN_NS)
        sp = softplc_data(e, "transition")
        if sp is not None and inline is not None and cond.get("negated") != "true":
            st = inline.find("ST", PLCOPEN_NS)
            written, was = sp.find("text", SOFTPLC_NS), sp.find("as", SOFTPLC_NS)
            if st is not None and written is not None and was is not None and (
                    fingerprint(str(formatted(st))) == fingerprint(was.text)):
                return written.ystr()
        text = self._condition_text(level, t, cond)
        if cond.get("negated") == "true":
            text = compose(["NOT (", text, ")"], cond.loc)
        return self._text(text)

    def _condition_text(self, level: Level, t: GTransition, cond: Element) -> YStr:
        inline = cond.find("inline", PLCOPEN_NS)
        if inline is not None:
            return self._body_expression(inline, f"localId {t.id}: the transition's inline "
                                                 "condition", None)
        ref = cond.find("reference", PLCOPEN_NS)
        if ref is not None:
            name = ref.get("name") or ""
            body_owner = self.transitions.get(name.lower())
            if body_owner is None:  # CODESYS: a bool variable as the condition
                return plain(name, ref.loc)
            body = body_owner.find("body", PLCOPEN_NS)
            if body is None:
                raise SourceError(body_owner.loc, f"transition '{name}' has no body")
            return self._body_expression(body, f"transition '{name}'",
                                         body_owner.get("name") or name)
        point = cond.find("connectionPointIn", PLCOPEN_NS)
        if point is not None:
            return self._network(level).point(point)
        raise SourceError(cond.loc, f"localId {t.id}: expected an inline condition, a "
                                    "reference or a connection in <condition>")

    def _body_expression(self, body: Element, what: str, name: str | None) -> YStr:
        """A condition from a body: ST (``expr``, ``:= expr;`` or ``NAME := expr;``), or
        an FBD/LD network ending at an output variable or a coil of the transition's
        name."""
        st = body.find("ST", PLCOPEN_NS)
        if st is not None:
            return _st_expression(formatted(st), name)
        for lang in ("FBD", "LD"):
            net = body.find(lang, PLCOPEN_NS)
            if net is None or name is None:
                continue
            for e in net.children:
                var = e.find("variable" if e.tag == "coil" else "expression", PLCOPEN_NS)
                if e.tag in ("outVariable", "coil") and var is not None and (
                        var.text.strip().lower() == name.lower()):
                    point = e.find("connectionPointIn", PLCOPEN_NS)
                    if point is None:
                        raise SourceError(e.loc, f"{what}: its {e.tag} is not connected")
                    return Network(net).point(point)
            raise SourceError(net.loc, f"{what}: expected an output variable or a coil named "
                                       f"'{name}' in its {lang} body")
        lang = body.children[0].tag if body.children else "nothing"
        raise SourceError(body.loc, f"{what} is written in {lang}: softplc reads conditions "
                                    "in ST, or FBD/LD made of variables, contacts and gates")

    # -- actions ------------------------------------------------------------------------------
    def _actions(self, level: Level, st: GStep) -> list[tuple[YStr, Loc]]:
        out: list[tuple[YStr, Loc]] = []
        vendor = codesys_attributes(st.e)
        for key, q in (("entry", "P1"), ("main", "N"), ("exit", "P0")):
            name = vendor.get(key, "")
            where = f"localId {st.id} (step '{st.name}'), CODESYS {key} action"
            if name and name.lower() not in self.actions:
                self.note(st.e.loc, f"{where} '{name}' left out: the file holds no action of "
                                    "that name")
            elif name:
                text = self._reference(st.e, where, q, None, name, plain(name, st.e.loc))
                if text is not None:
                    out.append((text, st.e.loc))
        blocks = sorted(level.blocks.get(st.name, []),
                        key=lambda b: (position(b)[1], position(b)[0], b.loc.line))
        for b in blocks:
            if b.get("negated") == "true":
                self.note(b.loc, f"localId {b.get('localId')} (action block of step "
                                 f"'{st.name}'): 'negated' left out (IEC 61131-3 gives an "
                                 "action block no negation)")
            for k, a in enumerate(b.findall("action", PLCOPEN_NS), 1):
                text = self._action(a, f"localId {b.get('localId')} (action block of step "
                                       f"'{st.name}'), action {k}")
                if text is not None:
                    out.append((text, a.loc))
        return out

    def _action(self, a: Element, where: str) -> YStr | None:
        """The action text of an ``action`` association, or None (left out, noted)."""
        q = (a.get("qualifier") or "N").strip()
        if q not in QUALIFIERS:
            raise SourceError(a.loc, f"{where}: unknown qualifier '{q}': expected one of "
                                     f"{' '.join(QUALIFIERS)}")
        ref, inline = a.find("reference", PLCOPEN_NS), a.find("inline", PLCOPEN_NS)
        st = inline.find("ST", PLCOPEN_NS) if inline is not None else None
        duration = a.get("duration")
        raw_body = (ref.get("name") or "") if ref is not None else (
            str(formatted(st)) if st is not None else "")
        sp = softplc_data(a, "action")
        if sp is not None:
            written, was = sp.find("text", SOFTPLC_NS), sp.find("as", SOFTPLC_NS)
            if written is not None and was is not None and fingerprint(was.text) == fingerprint(
                    native_text(q, duration, raw_body)):
                return written.ystr()
        if q == "DL":
            self.note(a.loc, f"{where}: qualifier DL left out with its action: IEC 61131-3 "
                             "gives DL no meaning (softplc has N S R L D P P1 P0 SD DS SL)")
            return None
        dtext: str | None = None
        if q in TIMED:
            if duration is None or parse_literal(
                    strip_time_prefix(duration.strip()).replace("_", "")) is None:
                self.note(a.loc, f"{where}: {q} action left out: its duration "
                                 f"'{duration or ''}' is no time literal (softplc needs a "
                                 "constant time such as T#2s)")
                return None
            dtext = duration.strip().replace("_", "")
        elif duration:
            self.note(a.loc, f"{where}: duration '{duration}' left out: qualifier {q} takes "
                             "none")
        if a.get("indicator"):
            self.note(a.loc, f"{where}: indicator '{a.get('indicator')}' left out (it only "
                             "shows a variable beside the action)")
        if ref is not None:
            name = ref.get("name") or ""
            return self._reference(a, where, q, dtext, name, plain(name, ref.loc))
        if st is None:
            lang = inline.children[0].tag if inline is not None and inline.children else None
            self.note(a.loc, f"{where} left out: " + (
                f"its body is written in {lang} (softplc reads ST)" if lang else
                "it has no reference and no inline body"))
            return None
        body = formatted(st)
        if not body.strip():
            self.note(a.loc, f"{where} left out: its inline body is empty")
            return None
        prefix = native_text(q, dtext, "")
        if native_text(q, dtext, str(body)) == str(body):  # softplc's 'on EVENT do'
            return self._text(body)
        return self._text(compose([prefix + " ", body], a.loc))

    def _reference(self, a: Element, where: str, q: str, dtext: str | None, name: str,
                   at: YStr) -> YStr | None:
        """An action that names a POU action (its ST body) or a bool variable."""
        action = self.actions.get(name.lower())
        prefix = native_text(q, dtext, "") + " "
        if action is None:
            if q == "P1":  # a pulse on activation: softplc's P
                prefix = native_text("P", dtext, "") + " "
            elif q == "P0":
                self.note(a.loc, f"{where}: P0 {name} left out: softplc has no pulse of a "
                                 "variable on deactivation (write 'P0 x := ...' in ST)")
                return None
            return self._text(compose([prefix, at], a.loc))
        self.used_actions.add(name.lower())
        body_e = action.find("body", PLCOPEN_NS)
        st = body_e.find("ST", PLCOPEN_NS) if body_e is not None else None
        if st is None:
            lang = body_e.children[0].tag if body_e is not None and body_e.children else "nothing"
            self.note(a.loc, f"{where}: action '{name}' left out: it is written in {lang} "
                             "(softplc reads ST)")
            return None
        if q in ("S", "R", "SD", "DS", "SL"):
            self.note(a.loc, f"{where}: {q} {name} left out: softplc stores bool variables "
                             "only (an action with statements has no S/R/SD/DS/SL)")
            return None
        body = formatted(st)
        if not body.strip():
            self.note(a.loc, f"{where}: action '{name}' left out: its body is empty")
            return None
        return self._text(compose([prefix, body], a.loc))


def _st_expression(text: YStr, name: str | None) -> YStr:
    """The expression of a transition's ST body: ``expr``, ``:= expr;`` or
    ``NAME := expr;`` (IEC 61131-3's forms)."""
    try:
        toks = Lexer(str(text), text.pos).tokens()
    except SourceError:
        return text
    words = [t for t in toks if t.kind not in ("NL", "EOF")]
    start, end = 0, len(text)
    if len(words) >= 2 and words[0].kind == "NAME" and words[1].text == ":=" and (
            name is None or words[0].text.lower() == name.lower()):
        start = words[1].end
    elif words and words[0].text == ":=":
        start = words[0].end
    while words and words[-1].text == ";":
        end = words[-1].start
        words.pop()
    return sub(text, start, end)
