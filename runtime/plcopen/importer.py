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
from runtime.language import ast as A
from runtime.language.grafcetfile import GrafcetLoader
from runtime.language.lexer import Lexer
from runtime.language.model import Grafcet, Qualifier
from runtime.language.signatures import FB_MEMBERS, TIMER_METHODS
from runtime.language.typecheck import FLAGS_BOOL, FLAGS_STRING, SYSTEM_BOOL
from runtime.language.yamlsrc import YList, YMap, YStr
from runtime.plcopen.globalvars import Global, Globals
from runtime.plcopen.interface import Interface, Var, iec_type, read_interface, softplc_data
from runtime.plcopen.network import Network, NotCarried
from runtime.plcopen.order import order
from runtime.plcopen.program import Plan, plan, task_of
from runtime.plcopen.schema import PLCOPEN_NS, QUALIFIERS, SOFTPLC_NS, TIMED
from runtime.plcopen.sfcgraph import GStep, GTransition, Level, position, read_level
from runtime.plcopen.texts import (
    compose,
    fingerprint,
    formatted,
    native_text,
    plain,
    pou_action_as,
    pou_action_mark,
    spell_as_declared,
    sub,
)
from runtime.plcopen.vendor import codesys_attributes, codesys_objects, is_codesys
from runtime.plcopen.xmltree import Element, parse_xml


@dataclass(frozen=True)
class Note:
    """Something of the file the chart does not carry, or carries changed (``lost``), or a
    choice the importer made that the user should know of (``lost=False``)."""

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
    plan: Plan = field(default_factory=Plan)  # the plant's instances and wiring


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
    tasks = task_of(root)
    scopes = Globals(root, _users(all_pous))
    for p in sfc_pous:
        name = p.get("name") or ""
        seen = scopes.visible(name)
        notes: list[Note] = []
        doc, iface = _PouImporter(path, p, codesys, notes, seen).run()
        g = GrafcetLoader(path, doc).load()
        mixed = _mixed(g)
        if mixed:  # again, with S/R/N on those variables as statements (matiec's meaning)
            notes = []
            doc, iface = _PouImporter(path, p, codesys, notes, seen, mixed).run()
            g = GrafcetLoader(path, doc).load()
        _constants_unwritten(g, iface)
        result.notes += notes
        instance, cycle, _ = tasks.get(name, (name, None, root))
        result.charts.append(ImportedChart(name, doc, g, iface, instance, cycle))

    def told(loc: Loc, message: str, lost: bool) -> None:
        result.notes.append(Note(loc, message, lost))

    result.plan = plan(root, all_pous, {(p.get("name") or "").lower(): p for p in sfc_pous},
                       scopes.visible, told)
    _shared_globals(result)
    return result


def _shared_globals(result: ImportResult) -> None:
    """A global that several instances of the plant reach as memory: one note each (every
    instance keeps its own copy: a chart's memory is its own)."""
    count: dict[str, list[str]] = {}
    by_pou = {c.pou: c for c in result.charts}
    for inst in result.plan.instances:
        chart = by_pou.get(inst.pou)
        for v, _ in chart.interface.memory if chart is not None else []:
            if v.shared:
                count.setdefault(v.shared, []).append(inst.name)
    for c in result.charts:
        for v, _ in c.interface.memory:
            users = count.get(v.shared, [])
            if v.shared and len(users) > 1:
                result.notes.append(Note(v.loc, f"the global {v.shared} is reached by "
                                                f"{len(users)} instances ({', '.join(users)}): "
                                                "each keeps its own copy (a chart's memory is "
                                                "its own)"))


def _users(pous: list[Element]) -> dict[str, set[str]]:
    """POU (lower case) -> the POUs that declare an instance of it."""
    out: dict[str, set[str]] = {}
    for p in pous:
        iface = p.find("interface", PLCOPEN_NS)
        for v in iface.iter() if iface is not None else []:
            if v.tag == "derived":
                out.setdefault((v.get("name") or "").lower(), set()).add(
                    (p.get("name") or "").lower())
    return out


def _assigned(g: Grafcet) -> set[str]:
    """The variables the statements of the chart's actions assign."""
    out: set[str] = set()
    for a in g.actions():
        for root in a.body or []:
            for n in A.walk(root):
                if isinstance(n, A.Assign):
                    out.add(n.target.name)
    return out


def _mixed(g: Grafcet) -> frozenset[str]:
    """The bool variables that statements of the chart's actions assign and that an S, R
    or N association also names."""
    targets = {a.target for a in g.actions() if a.target is not None and a.cond is None
               and a.qualifier in (Qualifier.S, Qualifier.R, Qualifier.N)}
    return frozenset(targets & _assigned(g))


def _constants_unwritten(g: Grafcet, iface: Interface) -> None:
    """A CONSTANT of the file is memory of the chart: an error if the chart writes it."""
    constants = {v.name: v for v, _ in iface.memory if v.constant}
    if not constants:
        return
    written = _assigned(g) | {a.target for a in g.actions() if a.target is not None}
    for s in (*g.pre, *g.post):
        for n in A.walk(s.node):
            if isinstance(n, A.Assign):
                written.add(n.target.name)
            elif isinstance(n, A.CallStmt) and n.call.method == "Set":
                written.add(n.call.obj)
    for name in sorted(set(constants) & written):
        v: Var = constants[name]
        raise SourceError(v.loc, f"'{name}' is CONSTANT in the file and the chart writes it "
                                 "(IEC 61131-3 refuses that)")


def _sfc_body(pou: Element) -> Element | None:
    for body in pou.findall("body", PLCOPEN_NS):
        sfc = body.find("SFC", PLCOPEN_NS)
        if sfc is not None:
            return sfc
    return None


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
    def __init__(self, path: str, pou: Element, codesys: bool, notes: list[Note],
                 globals_: dict[str, Global] | None = None,
                 mixed: frozenset[str] = frozenset()) -> None:
        self.path, self.pou, self.codesys, self.notes = path, pou, codesys, notes
        self.globals = globals_
        self.mixed = mixed  # bool variables statements assign: their S/R/N as statements
        self.name = pou.get("name") or ""
        self.actions = self._named(pou, "actions", "action")
        self.transitions = self._named(pou, "transitions", "transition")
        self.spelling: dict[str, str] = {}
        self.uses: dict[str, int] = {}  # POU transition name (lower case) -> references
        self.used_actions: set[str] = set()  # POU action names (lower case) steps use
        self.networks: dict[int, Network] = {}  # per level (id): its FBD/LD elements
        self.names_given: set[str] = set()  # transition names, unique in a chart
        self.fbs: dict[str, tuple[str, str]] = {}  # function blocks: lower case -> (name, type)
        self.calls: list[YStr] = []  # the calls of the conditions' function blocks
        self.bodies: dict[str, YStr] = {}  # POU transition (lower case) -> its condition

    def note(self, loc: Loc, message: str, lost: bool = True) -> None:
        self.notes.append(Note(loc, message, lost))

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
        iface = read_interface(pou, self.note, self.globals)
        self.fbs = {name.lower(): (name, kind) for name, kind, _ in iface.blocks}
        sfc = _sfc_body(pou)
        assert sfc is not None
        level = read_level(sfc, self.note)
        self._spelling(iface, level)
        self._count_references(level)
        doc = _map(pou.loc)
        _put(doc, "grafcet", plain(self.name, pou.loc), pou.loc)
        self._description(doc, level)
        chart = softplc_data(pou, "chart")
        if chart is not None and chart.get("scan"):
            _put(doc, "scan", plain(chart.get("scan") or "", chart.loc), chart.loc)
        elif self.codesys:
            _put(doc, "scan", plain("codesys", pou.loc), pou.loc)
            self.note(pou.loc, f"POU '{self.name}' comes from CODESYS: imported with 'scan: "
                               "codesys' (CODESYS's processing order, docs/semantics.md)",
                      lost=False)
        self._variables(doc, iface)
        self._equations(doc, chart, "pre")
        steps, transitions = self._level(level, None)
        _put(doc, "steps", steps, sfc.loc)
        if transitions:
            _put(doc, "transitions", transitions, sfc.loc)
        self._equations(doc, chart, "post", self.calls)
        if self.calls:
            self.note(sfc.loc, f"POU '{self.name}': the function blocks of its transitions' "
                               f"networks ({len(self.calls)}) are called in 'post', in every "
                               "scan after the actions, as Beremiz and matiec call them",
                      lost=False)
        self._used_transitions()
        return doc, iface

    def _description(self, doc: YMap, level: Level) -> None:
        """The POU's documentation, then the comments of its SFC body (top to bottom, left
        to right; a chart has no free texts), as the chart's description."""
        texts: list[tuple[str, Loc]] = []
        docu = self.pou.find("documentation", PLCOPEN_NS)
        if docu is not None and str(formatted(docu)).strip():
            texts.append((str(formatted(docu)), docu.loc))
        comments: list[Element] = []
        stack = [level]
        while stack:
            lv = stack.pop()
            comments += lv.comments
            stack += [s.macro for s in lv.steps.values() if s.macro is not None]
        for c in sorted(comments, key=lambda c: (position(c)[1], position(c)[0], c.loc.line)):
            content = c.find("content", PLCOPEN_NS)
            text = str(formatted(content)).strip() if content is not None else ""
            if text:
                texts.append((text, c.loc))
                self.note(c.loc, f"localId {c.get('localId')}: comment kept in the chart's "
                                 "description", lost=False)
        if texts:
            _put(doc, "description", "\n\n".join(t for t, _ in texts), texts[0][1])

    @staticmethod
    def _equations(doc: YMap, chart: Element | None, part: str,
                   more: list[YStr] | None = None) -> None:
        """pre or post, from softplc's data (PLCopen has no element for them), then
        ``more``."""
        texts = [(e.ystr(), e.loc) for e in chart.findall(part, SOFTPLC_NS)] if chart else []
        texts += [(t, t.loc) for t in more or []]
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
                if v.type == "bool" and not v.description:
                    items.append((plain(v.name, v.loc), v.loc))
                    continue
                m = _map(v.loc)
                typ: Any = plain(v.type, v.loc)
                iec = iec_type(v)
                if v.description or iec:
                    typ = _map(v.loc)
                    _put(typ, "type", plain(v.type, v.loc), v.loc)
                    if v.description:
                        _put(typ, "description", v.description, v.loc)
                    if iec:
                        _put(typ, "iec_type", plain(iec, v.loc), v.loc)
                _put(m, v.name, typ, v.loc)
                items.append((m, v.loc))
            if items:
                _put(doc, key, _list(items[0][1], items), items[0][1])
        if iface.memory:
            mem = _map(iface.memory[0][0].loc)
            for v, retained in iface.memory:
                init = v.init if v.init is not None else _zero(v.type)
                value: Any = plain(format_ns(int(init)), v.loc) if v.type == "time" else init  # type: ignore[call-overload]
                iec = iec_type(v)
                if retained or v.renamed_from or v.description or iec:
                    spec = _map(v.loc)
                    _put(spec, "init", value, v.loc)
                    if retained:
                        _put(spec, "retain", True, v.loc)
                    if v.renamed_from:
                        _put(spec, "renamed_from", plain(v.renamed_from, v.loc), v.loc)
                    if v.description:
                        _put(spec, "description", v.description, v.loc)
                    if iec:
                        _put(spec, "iec_type", plain(iec, v.loc), v.loc)
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
            net = self.networks[id(level)] = Network(level.sfc, self.fbs)
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
            known = self.bodies.get(name.lower())
            if known is None:  # read once: its blocks are called once
                known = self.bodies[name.lower()] = self._body_expression(
                    body, f"transition '{name}'", body_owner.get("name") or name)
            return known
        point = cond.find("connectionPointIn", PLCOPEN_NS)
        if point is not None:
            net = self._network(level)
            text = self._carried(lambda: net.point(point))
            self.calls += net.program
            net.program.clear()
            return text
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
                    network = Network(net, self.fbs)
                    text = self._carried(lambda: network.point(point))  # noqa: B023 - now
                    self.calls += network.program
                    for c in net.children:
                        if c.tag == "comment":
                            self.note(c.loc, f"{what}: comment localId {c.get('localId')} "
                                             "left out (a condition has no free texts)")
                    return text
            raise SourceError(net.loc, f"{what}: expected an output variable or a coil named "
                                       f"'{name}' in its {lang} body")
        lang = body.children[0].tag if body.children else "nothing"
        raise SourceError(body.loc, f"{what} is written in {lang}: softplc reads conditions "
                                    "in ST, or FBD/LD (variables, contacts, gates, "
                                    "comparisons, function blocks)")

    @staticmethod
    def _carried(read: Any) -> YStr:
        """A condition's network read: what it holds that has no form in the language is an
        error there (its evolution would change)."""
        try:
            text: YStr = read()
        except NotCarried as exc:
            raise SourceError(exc.loc, f"{exc.message} (in a transition's condition)"
                              ) from None
        return text

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
                out += [(text, st.e.loc) for text in
                        self._reference(st.e, where, q, None, name, plain(name, st.e.loc))]
        blocks = sorted(level.blocks.get(st.name, []),
                        key=lambda b: (position(b)[1], position(b)[0], b.loc.line))
        for b in blocks:
            if b.get("negated") == "true":
                self.note(b.loc, f"localId {b.get('localId')} (action block of step "
                                 f"'{st.name}'): 'negated' left out (IEC 61131-3 gives an "
                                 "action block no negation)")
            for k, a in enumerate(b.findall("action", PLCOPEN_NS), 1):
                out += [(text, a.loc) for text in
                        self._action(a, f"localId {b.get('localId')} (action block of step "
                                        f"'{st.name}'), action {k}")]
        return out

    def _action(self, a: Element, where: str) -> list[YStr]:
        """The action texts of an ``action`` association (none: left out, noted)."""
        q = (a.get("qualifier") or "N").strip()
        if q not in QUALIFIERS:
            raise SourceError(a.loc, f"{where}: unknown qualifier '{q}': expected one of "
                                     f"{' '.join(QUALIFIERS)}")
        ref, inline = a.find("reference", PLCOPEN_NS), a.find("inline", PLCOPEN_NS)
        st = inline.find("ST", PLCOPEN_NS) if inline is not None else None
        duration = a.get("duration")
        raw_body = self._referenced(ref.get("name") or "") if ref is not None else (
            str(formatted(st)) if st is not None else "")
        sp = softplc_data(a, "action")
        if sp is not None:
            written, was = sp.find("text", SOFTPLC_NS), sp.find("as", SOFTPLC_NS)
            if written is not None and was is not None and fingerprint(was.text) == fingerprint(
                    native_text(q, duration, raw_body)):
                if ref is not None and (ref.get("name") or "").lower() in self.actions:
                    self.used_actions.add((ref.get("name") or "").lower())
                return [written.ystr()]
        if q == "DL":
            self.note(a.loc, f"{where}: qualifier DL left out with its action: IEC 61131-3 "
                             "gives DL no meaning (softplc has N S R L D P P1 P0 SD DS SL)")
            return []
        dtext: str | None = None
        if q in TIMED:
            if duration is None or not duration.strip():
                raise SourceError(a.loc, f"{where}: qualifier {q} without a duration: IEC "
                                         f"61131-3 times {q} (expected duration=\"T#2s\" "
                                         "or another time)")
            if parse_literal(strip_time_prefix(duration.strip()).replace("_", "")) is None:
                self.note(a.loc, f"{where}: {q} action left out: its duration "
                                 f"'{duration}' is no time literal (softplc needs a "
                                 "constant time such as T#2s)")
                return []
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
        body = self._statements(inline, where, a.loc) if inline is not None else None
        if inline is None:
            self.note(a.loc, f"{where} left out: it has no reference and no inline body")
        if body is None:
            return []
        if not body.strip():
            self.note(a.loc, f"{where} left out: its inline body is empty")
            return []
        prefix = native_text(q, dtext, "")
        if st is not None and native_text(q, dtext, str(body)) == str(body):
            return [self._text(body)]  # softplc's 'on EVENT do'
        # the names of the body spelled as declared, never the qualifier (a variable 'n'
        # would make the qualifier N 'n')
        return [compose([prefix + " ", self._text(body)], a.loc)]

    def _referenced(self, name: str) -> str:
        """What an export wrote of a reference (softplc's ``sp:as``): the name, and the ST
        body of the POU action it names (an edit of either is read from the file)."""
        action = self.actions.get(name.lower())
        body = action.find("body", PLCOPEN_NS) if action is not None else None
        st = body.find("ST", PLCOPEN_NS) if body is not None else None
        return name if st is None else pou_action_as(name, str(formatted(st)))

    def _statements(self, body: Element, where: str, at: Loc) -> YStr | None:
        """The statements of an action's body: its ST, or its FBD/LD network as ST (the
        comments of the network as ``//`` lines first); None if it cannot be read (noted)."""
        st = body.find("ST", PLCOPEN_NS)
        if st is not None:
            return formatted(st)
        for lang in ("LD", "FBD"):
            net = body.find(lang, PLCOPEN_NS)
            if net is None:
                continue
            network = Network(net, self.fbs)
            try:
                lines = network.statements()
            except NotCarried as exc:
                self.note(exc.loc, f"{where} left out: {exc.message}")
                return None
            comments = sorted((c for c in net.children if c.tag == "comment"),
                              key=lambda c: (position(c)[1], position(c)[0]))
            texts: list[str | YStr] = []
            for c in comments:
                content = c.find("content", PLCOPEN_NS)
                for line in str(formatted(content)).splitlines() if content else []:
                    line = "".join(ch if ch.isprintable() else " " for ch in line).strip()
                    texts += [f"// {line}" if line else "//", "\n"]
            for k, line in enumerate(lines):
                texts += ["\n"] if k else []
                texts.append(line)
            return compose(texts, net.loc) if lines else plain("", net.loc)
        found = body.children[0].tag if body.children else None
        self.note(at, f"{where} left out: " + (
            f"it is written in {found} (softplc reads ST, FBD and LD)" if found else
            "its body is empty"))
        return None

    def _reference(self, a: Element, where: str, q: str, dtext: str | None, name: str,
                   at: YStr) -> list[YStr]:
        """An action that names a POU action (its body) or a bool variable."""
        action = self.actions.get(name.lower())
        prefix = native_text(q, dtext, "") + " "
        if action is None:
            if q == "P1":  # a pulse on activation: softplc's P
                prefix = native_text("P", dtext, "") + " "
            elif q == "P0":
                self.note(a.loc, f"{where}: P0 {name} left out: softplc has no pulse of a "
                                 "variable on deactivation (write 'P0 x := ...' in ST)")
                return []
            declared = self.spelling.get(name.lower(), name)
            if declared in self.mixed and q in ("S", "R", "N"):
                return self._as_statements(a, where, q, declared, at)
            return [compose([prefix, self._text(at)], a.loc)]
        self.used_actions.add(name.lower())
        body_e = action.find("body", PLCOPEN_NS)
        if body_e is None:
            self.note(a.loc, f"{where}: action '{name}' left out: it has no body")
            return []
        body = self._statements(body_e, f"{where}: action '{name}'", a.loc)
        if body is None:
            return []
        if q in ("S", "R", "SD", "DS", "SL"):
            self.note(a.loc, f"{where}: {q} {name} left out: softplc stores bool variables "
                             "only (an action with statements has no S/R/SD/DS/SL)")
            return []
        if not body.strip():
            self.note(a.loc, f"{where}: action '{name}' left out: its body is empty")
            return []
        declared_name = action.get("name") or name
        return [compose([prefix, pou_action_mark(declared_name) + " ", self._text(body)],
                        a.loc)]

    def _as_statements(self, a: Element, where: str, q: str, name: str, at: YStr
                       ) -> list[YStr]:
        """S, R or N on a bool variable that statements of the chart also assign, with
        matiec's meaning: the variable is written only while the association's step is
        active (and, for N, once when it is left), so what the statements write lasts
        (softplc's action control writes an action's variable in every scan)."""
        value = "FALSE" if q == "R" else "TRUE"
        out = [compose(["N ", at, f" := {value}"], a.loc)]
        if q == "N":
            out.append(compose(["P0 ", at, " := FALSE"], a.loc))
        self.note(a.loc, f"{where}: {q} {name} written as the statements "
                         f"{' and '.join(repr(str(t)) for t in out)}: statements of the chart "
                         f"also assign {name}, and matiec writes a variable only while an "
                         "association sets or resets it (docs/plcopen.md)", lost=False)
        return [self._text(t) for t in out]


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
