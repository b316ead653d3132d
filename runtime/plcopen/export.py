"""``softplc export``: a chart as one PLCopen project holding it as an SFC POU.

What maps to what is docs/plcopen.md's table. In short: steps, macro-steps (their
expansion in the macro-step's ``body``), transitions (condition as inline ST), selection and
simultaneous divergences and convergences, jump steps for the links that go back up, action
blocks with their qualifiers; the chart's variables as the POU's interface. Texts are
written in Structured Text (``language/unparse.py``, ``st_text``); what PLCopen has no
element for (the texts as written, pre/post equations, min/max, seed timers, the scan model,
source and sink transitions, the order of steps and transitions) goes into ``addData`` in
softplc's namespace, so that ``softplc import`` gives the chart back as it was.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from datetime import datetime

from drivers.durations import format_ns
from runtime.drawing.layout import BAR_W, macro_of_transition
from runtime.errors import SourceError
from runtime.language import ast as A
from runtime.language.model import Action, Grafcet, Qualifier, Step, Transition, VarKind
from runtime.language.unparse import st_real, st_statements, st_text
from runtime.plcopen.geometry import (
    BAR_H,
    DOUBLE_H,
    JUMP_H,
    JUMP_W,
    Geometry,
    Point,
    route,
)
from runtime.plcopen.schema import (
    EXPORT_TYPES,
    PLCOPEN_NS,
    SOFTPLC_NS,
    SOFTPLC_PREFIX,
    XHTML_NS,
)
from runtime.plcopen.texts import fingerprint, native_text, pou_action_as, pou_action_of
from runtime.plcopen.xmlwrite import Node, serialize

SP = SOFTPLC_PREFIX + ":"
#: what an exported project names its configuration, resource, task and instance (Beremiz's
#: own defaults, so that Beremiz builds the project as it is)
CONFIGURATION, RESOURCE, TASK, INSTANCE = "config", "resource1", "task0", "instance0"
#: the task's interval: a plant's default cycle (the chart alone has none)
TASK_INTERVAL = "T#10ms"


def export_chart(g: Grafcet, *, version: str = "", created: datetime | None = None,
                 layout: str = "python") -> str:
    """The PLCopen XML text of a project holding chart ``g`` as an SFC program."""
    return serialize(project(g, version=version, created=created, layout=layout))


def project(g: Grafcet, *, version: str = "", created: datetime | None = None,
            layout: str = "python") -> Node:
    root, pous = project_head(g.name, version, created)
    chart_pou(pous, g, "program", layout)
    task(root, TASK_INTERVAL).add("pouInstance", {"name": INSTANCE, "typeName": g.name})
    return root


def project_head(name: str, version: str, created: datetime | None) -> tuple[Node, Node]:
    """A project named ``name``: its root and its ``pous`` (empty)."""
    when = (created or datetime.now()).replace(microsecond=0).isoformat()
    root = Node("project", {"xmlns": PLCOPEN_NS, "xmlns:xhtml": XHTML_NS,
                            f"xmlns:{SOFTPLC_PREFIX}": SOFTPLC_NS})
    root.add("fileHeader", {"companyName": "softplc", "productName": "softplc",
                            "productVersion": version or "0", "creationDateTime": when})
    head = root.add("contentHeader", {"name": name})
    coord = head.add("coordinateInfo")
    for part in ("fbd", "ld", "sfc"):
        coord.add(part).add("scaling", {"x": "0", "y": "0"})
    info = head.add("addDataInfo").add("info", {"name": SOFTPLC_NS, "version": "1.0",
                                                "vendor": "urn:softplc"})
    _text(info.add("description"), "softplc's own data of a chart (docs/plcopen.md): the "
          "texts as written, pre/post equations, min/max step times, seed timers, the scan "
          "model, source and sink transitions, the order of steps and transitions")
    types = root.add("types")
    types.add("dataTypes")
    return root, types.add("pous")


def chart_pou(pous: Node, g: Grafcet, pou_type: str, layout: str) -> Node:
    """Chart ``g`` as an SFC POU of ``pous`` (``pou_type`` program or functionBlock)."""
    pou = pous.add("pou", {"name": g.name, "pouType": pou_type})
    _interface(g, pou.add("interface"))
    shared = pou_actions(g)
    if shared:
        actions = pou.add("actions")
        for name, body in shared.values():
            _text(actions.add("action", {"name": name}).add("body").add("ST"), body,
                  cdata=True)
    ex = _Exporter(g, Geometry(g, layout), shared)
    sfc = pou.add("body").add("SFC")
    ex.level(None, sfc)
    _shift(sfc)
    data = _data(pou)
    chart = data.add(SP + "chart", {"scan": g.scan.value} if g.scan.value != "immediate" else {})
    for part in ("pre", "post"):
        for st in getattr(g, part):
            chart.add(SP + part, text=st.text)
    if g.description:
        _text(pou.add("documentation"), g.description)
    return pou


def task(root: Node, interval: str) -> Node:
    """The project's configuration, resource and task (of ``interval``, ``T#10ms``)."""
    return (root.add("instances").add("configurations")
            .add("configuration", {"name": CONFIGURATION})
            .add("resource", {"name": RESOURCE})
            .add("task", {"name": TASK, "priority": "0", "interval": interval}))


def _text(parent: Node, text: str, cdata: bool = False) -> None:
    """``formattedText``: one XHTML paragraph."""
    if cdata:
        parent.add("xhtml:p", cdata=text)
    else:
        parent.add("xhtml:p", text=text)


def _data(parent: Node) -> Node:
    """softplc's ``data`` element in ``parent``'s ``addData``."""
    return parent.add("addData").add("data", {"name": SOFTPLC_NS, "handleUnknown": "preserve"})


# -- the interface ---------------------------------------------------------------------------
def value_text(t: A.Type, v: object) -> str:
    """An initial value in IEC 61131-3 literal form."""
    if t is A.Type.BOOL:
        return "TRUE" if v else "FALSE"
    if t is A.Type.TIME:
        return "T#" + format_ns(int(v))  # type: ignore[call-overload]
    return st_real(v) if isinstance(v, float) else str(v)


def _interface(g: Grafcet, iface: Node) -> None:
    lists: list[tuple[str, dict[str, str], list[Node]]] = []

    def var(name: str, type_node: Node, init: str | None = None,
            renamed: str | None = None, description: str = "") -> Node:
        v = Node("variable", {"name": name}, [Node("type", {}, [type_node])])
        if init is not None:
            v.add("initialValue").add("simpleValue", {"value": init})
        if renamed is not None:
            _data(v).add(SP + "variable", {"renamed_from": renamed})
        if description:
            _text(v.add("documentation"), description)
        return v

    for kind, tag in ((VarKind.INPUT, "inputVars"), (VarKind.OUTPUT, "outputVars")):
        vs = [var(v.name, Node(v.iec_type or EXPORT_TYPES[v.type.value]),
                  description=v.description)
              for v in g.variables.values() if v.kind is kind]
        lists.append((tag, {}, vs))
    # memory in its order: one localVars list per run of retained or not retained variables
    for retain, run in itertools.groupby(g.memory, key=lambda v: v.retain):
        lists.append(("localVars", {"retain": "true"} if retain else {},
                      [var(v.name, Node(v.iec_type or EXPORT_TYPES[v.type.value]),
                           value_text(v.type, v.init), v.renamed_from, v.description)
                       for v in run]))
    lists.append(("localVars", {}, [var(b.name, Node("derived", {"name": b.kind}))
                                    for b in g.blocks.values()]))
    for tag, attrs, vs in lists:
        if vs:
            iface.add(tag, attrs).children.extend(vs)
    if g.timers:
        timers = _data(iface).add(SP + "timers")
        for name in g.timers:
            timers.add(SP + "timer", {"name": name})


# -- the SFC body ----------------------------------------------------------------------------
def action_native(a: Action) -> tuple[str, str | None, str, str]:
    """(qualifier, duration, "reference" or "inline", name or ST body) of an action."""
    duration = "T#" + format_ns(a.time_ns) if a.time_ns is not None else None
    if a.target is not None and a.cond is None:
        return a.qualifier.value, duration, "reference", a.target
    if a.target is not None and a.cond is not None:  # softplc's conditional action
        return "N", None, "inline", f"{a.target} if {st_text(a.cond)}"
    assert a.body is not None
    if a.qualifier is Qualifier.EVENT:  # softplc's event action
        assert a.event is not None
        return "N", None, "inline", (f"on {st_text(a.event)} do\n"
                                     f"{st_statements(a.body, '    ')}")
    return a.qualifier.value, duration, "inline", st_statements(a.body)


def _marked(a: Action) -> str | None:
    """The POU action a statement action is marked with (``N (* action Blink *) ...``)."""
    if a.target is not None or a.body is None or a.qualifier is Qualifier.EVENT:
        return None
    return pou_action_of(a.text)


def pou_actions(g: Grafcet) -> dict[str, tuple[str, str]]:
    """The POU actions of the chart's marked step actions: lower-case name -> (name, ST
    body), in the order the steps first name them. Two different bodies under one name (IEC
    names ignore case) are refused at the second: a POU action has one body."""
    out: dict[str, tuple[str, str]] = {}
    first: dict[str, tuple[str, Action]] = {}
    for s in g.steps.values():
        for a in s.actions:
            name = _marked(a)
            if name is None:
                continue
            assert a.body is not None
            body = st_statements(a.body)
            key = name.lower()
            clash = next((v for v in g.variables if v.lower() == key), None)
            if clash is not None:
                raise SourceError(a.loc, f"cannot export action {a.text.strip()!r} of step "
                                  f"'{s.name}': it is marked as POU action '{name}', the name "
                                  f"of the chart's variable '{clash}' (a POU names each "
                                  "variable and action once): rename the mark")
            if key not in out:
                out[key], first[key] = (name, body), (s.name, a)
            elif fingerprint(out[key][1]) != fingerprint(body):
                step, other = first[key]
                raise SourceError(a.loc, f"cannot export action {a.text.strip()!r} of step "
                                  f"'{s.name}': it is marked as POU action '{name}', which "
                                  f"step '{step}' marks with other statements "
                                  f"({other.text.strip()!r}): a POU action has one body "
                                  "(make the statements the same, or rename one mark)")
    return out


@dataclass
class _Level:
    """The elements of one body: the chart's, or a macro-step's expansion."""

    steps: list[Step]
    trans: list[tuple[int, Transition]]
    step_id: dict[str, int] = field(default_factory=dict)
    trans_id: dict[int, int] = field(default_factory=dict)
    outs: dict[str, list[int]] = field(default_factory=dict)
    ins: dict[str, list[int]] = field(default_factory=dict)


class _Exporter:
    def __init__(self, g: Grafcet, geo: Geometry,
                 shared: dict[str, tuple[str, str]]) -> None:
        self.g, self.geo, self.shared = g, geo, shared
        self.ids = itertools.count(1)
        self.owner = macro_of_transition(g)
        self.order = {name: i for i, name in enumerate(g.steps)}

    def new_id(self) -> int:
        return next(self.ids)

    def level(self, macro: str | None, sfc: Node) -> None:
        g = self.g
        lv = _Level([s for s in g.steps.values() if s.parent == macro],
                    [(k, t) for k, t in enumerate(g.transitions) if self.owner.get(k) == macro])
        names = {s.name for s in lv.steps}
        for s in lv.steps:
            lv.step_id[s.name] = self.new_id()
            lv.outs[s.name], lv.ins[s.name] = [], []
        for k, t in lv.trans:
            lv.trans_id[k] = self.new_id()
            for n in (*t.sources, *t.targets):
                if n not in names:
                    where = f"macro-step {macro}'s expansion" if macro else "the chart"
                    raise SourceError(t.loc, f"cannot export transition {t.text!r}: it is "
                                      f"written in {where} but links step '{n}' of another "
                                      "level (PLCopen keeps each expansion in its macro-step's "
                                      "body): write it where its steps are")
            for src in dict.fromkeys(t.sources):
                lv.outs[src].append(k)
            for dst in dict.fromkeys(t.targets):
                lv.ins[dst].append(k)
        exit_point = {s.name: self.divergence(sfc, lv, s) for s in lv.steps}
        producers = self.transitions(sfc, lv, exit_point)
        for s in lv.steps:
            self.step(sfc, lv, s, producers)
        # steps (each with its action block) first, as a reader looks for them
        first = ("step", "macroStep", "actionBlock")
        sfc.children.sort(key=lambda e: e.tag not in first)

    # -- steps ----------------------------------------------------------------------------
    def divergence(self, sfc: Node, lv: _Level, s: Step) -> tuple[int, Point | None]:
        """(element, branch x or None) a transition leaving ``s`` connects to: the step, or
        its selection divergence when several transitions leave it."""
        outs = lv.outs[s.name]
        if len(outs) < 2:
            return lv.step_id[s.name], None
        geo = self.geo
        y = geo.split_y(s.name)
        sx, sy = geo.step_out(s.name)
        xs = [sx] + [self.input_x(k) for k in outs]
        x0 = min(xs)
        i = self.new_id()
        d = sfc.add("selectionDivergence", {"localId": str(i), "height": "1",
                                            "width": _n(max(xs) - x0)})
        _pos(d, x0, y)
        self.link(d.add("connectionPointIn"), (x0, y), (sx, y), lv.step_id[s.name], (sx, sy))
        for k in outs:
            _rel(d.add("connectionPointOut", {"formalParameter": ""}), (x0, y),
                 (self.input_x(k), y + 1))
        return i, (x0, y + 1)

    def input_x(self, k: int) -> float:
        """The x where a link from a step reaches transition ``k`` (its bar or its AND
        convergence line)."""
        return self.geo.bar(k)[0]

    def step(self, sfc: Node, lv: _Level, s: Step,
             producers: dict[tuple[int, str], tuple[int, Point]]) -> None:
        geo = self.geo
        x, y, w, h = geo.step_box(s.name)
        macro = s.macro is not None
        attrs = {"localId": str(lv.step_id[s.name]), "height": _n(h), "width": _n(w),
                 "name": s.name}
        if not macro:
            attrs["initialStep"] = "true" if s.initial else "false"
        e = sfc.add("macroStep" if macro else "step", attrs)
        _pos(e, x, y)
        pin_in = geo.step_in(s.name)
        links = [(k, producers[(k, s.name)]) for k in lv.ins[s.name] if (k, s.name) in producers]
        cin = e.add("connectionPointIn")
        if len(links) == 1:
            _, (pid, ppin) = links[0]
            self.link(cin, (x, y), pin_in, pid, ppin)
        elif links:
            pid, ppin = self.convergence(sfc, s, links)
            self.link(cin, (x, y), pin_in, pid, ppin)
        else:
            _rel(cin, (x, y), pin_in)
        out = e.add("connectionPointOut", {} if macro else {"formalParameter": ""})
        _rel(out, (x, y), geo.step_out(s.name))
        if macro:
            assert s.macro is not None
            self.level(s.name, e.add("body").add("SFC"))
        elif s.actions:
            _rel(e.add("connectionPointOutAction", {"formalParameter": ""}), (x, y),
                 geo.action_pin(s.name))
        sp = _data(e).add(SP + "step", {"order": str(self.order[s.name])})
        for key, ns in (("min", s.min_ns), ("max", s.max_ns)):
            if ns is not None:
                sp.attrs[key] = format_ns(ns)
        for key, flag in (("initial", macro and s.initial), ("entry", s.entry),
                          ("exit", s.exit)):
            if flag:
                sp.attrs[key] = "true"
        if s.renamed_from:
            sp.attrs["renamed_from"] = s.renamed_from
        if s.description:
            _text(e.add("documentation"), s.description)
        if s.actions:
            self.action_block(sfc, lv, s)

    def convergence(self, sfc: Node, s: Step, links: list[tuple[int, tuple[int, Point]]]
                    ) -> tuple[int, Point]:
        """A selection convergence above ``s`` joining ``links``; its id and output pin."""
        y = self.geo.join_y(s.name)
        sx = self.geo.step_in(s.name)[0]
        xs = [sx] + [ppin[0] for _, (_, ppin) in links]
        x0 = min(xs)
        i = self.new_id()
        c = sfc.add("selectionConvergence", {"localId": str(i), "height": "1",
                                             "width": _n(max(xs) - x0)})
        _pos(c, x0, y)
        for _, (pid, ppin) in links:
            self.link(c.add("connectionPointIn"), (x0, y), (ppin[0], y), pid, ppin)
        _rel(c.add("connectionPointOut"), (x0, y), (sx, y + 1))
        return i, (sx, y + 1)

    def action_block(self, sfc: Node, lv: _Level, s: Step) -> None:
        x, y, w, heights = self.geo.action_block(s.name)
        i = self.new_id()
        b = sfc.add("actionBlock", {"localId": str(i), "height": _n(sum(heights)),
                                    "width": _n(w)})
        _pos(b, x, y)
        self.link(b.add("connectionPointIn"), (x, y), (x, self.geo.action_pin(s.name)[1]),
                  lv.step_id[s.name], self.geo.action_pin(s.name))
        yy = 0.0
        for a, h in zip(s.actions, heights, strict=True):
            q, duration, kind, body = action_native(a)
            as_written = body
            marked = _marked(a)
            if marked is not None:  # a reference to the POU action written once
                name, st = self.shared[marked.lower()]
                kind, body, as_written = "reference", name, pou_action_as(name, st)
            attrs = {"localId": str(self.new_id()), "qualifier": q, "width": _n(w),
                     "height": _n(h)}
            if duration is not None:
                attrs["duration"] = duration
            e = b.add("action", attrs)
            e.add("relPosition", {"x": "0", "y": _n(yy)})
            yy += h
            if kind == "reference":
                e.add("reference", {"name": body})
            else:
                _text(e.add("inline").add("ST"), body, cdata=True)
            sp = _data(e).add(SP + "action")
            sp.add(SP + "text", text=a.text)
            sp.add(SP + "as", text=native_text(q, duration, as_written))

    # -- transitions ------------------------------------------------------------------------
    def transitions(self, sfc: Node, lv: _Level, exit_point: dict[str, tuple[int, Point | None]]
                    ) -> dict[tuple[int, str], tuple[int, Point]]:
        """Every transition of the level with what joins it to its steps; returns, for each
        (transition, target step) linked directly, the element the step's input connects to
        and that element's output pin (the others are jump steps)."""
        geo, c = self.geo, self.geo.c
        producers: dict[tuple[int, str], tuple[int, Point]] = {}
        # a link back up is a jump step; so is a branch of an AND divergence into a step that
        # has other links in (a selection convergence joins transitions only)
        jumps: set[tuple[int, str]] = set()
        for s in lv.steps:
            direct = []
            for k in lv.ins[s.name]:
                if (f"t:{k}", "s:" + geo.entry_leaf(s.name)) in c.back:
                    jumps.add((k, s.name))
                else:
                    direct.append(k)
            if len(direct) > 1:
                jumps |= {(k, s.name) for k in direct
                          if len(set(self.g.transitions[k].targets)) > 1}
        for k, t in lv.trans:
            bx, by = geo.bar(k)
            i = lv.trans_id[k]
            attrs = {"localId": str(i), "height": _n(BAR_H), "width": _n(BAR_W),
                     "priority": str(k + 1)}
            e = sfc.add("transition", attrs)
            top = (bx - BAR_W / 2, by - BAR_H / 2)
            _pos(e, *top)
            cin = e.add("connectionPointIn")
            sources = list(dict.fromkeys(t.sources))
            if len(sources) == 1:
                pid, branch = exit_point[sources[0]]
                ppin = (bx, branch[1]) if branch else geo.step_out(sources[0])
                self.link(cin, top, (bx, by - BAR_H / 2), pid, ppin)
            elif sources:
                pid, ppin = self.and_convergence(sfc, k, sources, exit_point)
                self.link(cin, top, (bx, by - BAR_H / 2), pid, ppin)
            else:
                _rel(cin, top, (bx, by - BAR_H / 2))
            _rel(e.add("connectionPointOut"), top, (bx, by + BAR_H / 2))
            inline = e.add("condition").add("inline", {"name": t.name})
            st = st_text(t.cond)
            _text(inline.add("ST"), st, cdata=True)
            sp = _data(e).add(SP + "transition", {"order": str(k)})
            for key, names in (("sources", t.sources), ("targets", t.targets)):
                if len(names) > 1:
                    sp.attrs[key] = " ".join(names)
            if t.name:
                sp.attrs["name"] = t.name
            if not t.sources:
                sp.attrs["source"] = "true"
            if not t.targets:
                sp.attrs["sink"] = "true"
            sp.add(SP + "text", text=t.text)
            sp.add(SP + "as", text=st)
            targets = list(dict.fromkeys(t.targets))
            out_pin = (bx, by + BAR_H / 2)
            branch_of: dict[str, tuple[int, Point]] = {}
            if len(targets) > 1:
                branch_of = self.and_divergence(sfc, k, targets, jumps, (i, out_pin))
            for dst in targets:
                pid, ppin = branch_of.get(dst, (i, out_pin))
                if (k, dst) in jumps:
                    self.jump(sfc, dst, pid, ppin)
                else:
                    producers[(k, dst)] = (pid, ppin)
        return producers

    def and_convergence(self, sfc: Node, k: int, sources: list[str],
                        exit_point: dict[str, tuple[int, Point | None]]) -> tuple[int, Point]:
        geo = self.geo
        bx, _ = geo.bar(k)
        y = geo.and_in_y(k)
        pins = []
        for s in sources:
            pid, branch = exit_point[s]
            sx = geo.step_out(s)[0]
            # from a selection divergence: its branch over this transition
            pins.append((pid, (self.input_x(k), branch[1]) if branch else geo.step_out(s), sx))
        xs = [bx] + [p[2] for p in pins]
        x0 = min(xs) - 12
        i = self.new_id()
        c = sfc.add("simultaneousConvergence", {"localId": str(i), "height": _n(DOUBLE_H),
                                                "width": _n(max(xs) + 12 - x0)})
        _pos(c, x0, y)
        for pid, ppin, sx in pins:
            self.link(c.add("connectionPointIn"), (x0, y), (sx, y), pid, ppin)
        _rel(c.add("connectionPointOut"), (x0, y), (bx, y + DOUBLE_H))
        return i, (bx, y + DOUBLE_H)

    def and_divergence(self, sfc: Node, k: int, targets: list[str],
                       jumps: set[tuple[int, str]], source: tuple[int, Point]
                       ) -> dict[str, tuple[int, Point]]:
        geo = self.geo
        bx, _ = geo.bar(k)
        y = geo.and_out_y(k)
        xs: dict[str, float] = {}
        right = bx
        for s in targets:
            if (k, s) in jumps:
                continue
            xs[s] = geo.step_in(s)[0]
            right = max(right, xs[s])
        for s in targets:
            if (k, s) in jumps:
                right += 2 * JUMP_W
                xs[s] = right
        x0 = min([bx, *xs.values()]) - 12
        i = self.new_id()
        d = sfc.add("simultaneousDivergence", {"localId": str(i), "height": _n(DOUBLE_H),
                                               "width": _n(max([bx, *xs.values()]) + 12 - x0)})
        _pos(d, x0, y)
        self.link(d.add("connectionPointIn"), (x0, y), (bx, y), *source)
        out: dict[str, tuple[int, Point]] = {}
        for s in targets:
            pin = (xs[s], y + DOUBLE_H)
            _rel(d.add("connectionPointOut", {"formalParameter": ""}), (x0, y), pin)
            out[s] = (i, pin)
        return out

    def jump(self, sfc: Node, target: str, pid: int, ppin: Point) -> None:
        x, y = ppin[0] - JUMP_W / 2, ppin[1] + 16
        e = sfc.add("jumpStep", {"localId": str(self.new_id()), "height": _n(JUMP_H),
                                 "width": _n(JUMP_W), "targetName": target})
        _pos(e, x, y)
        self.link(e.add("connectionPointIn"), (x, y), (ppin[0], y), pid, ppin)

    # -- connections ------------------------------------------------------------------------
    @staticmethod
    def link(cin: Node, origin: Point, pin: Point, producer: int, producer_pin: Point) -> None:
        """``cin`` (a connectionPointIn of an element at ``origin``, its pin at ``pin``)
        connected to element ``producer``'s output pin."""
        _rel(cin, origin, pin)
        conn = cin.add("connection", {"refLocalId": str(producer)})
        for px, py in route(pin, producer_pin):
            conn.add("position", {"x": _n(px), "y": _n(py)})


#: the margin left of and above the chart, px
MARGIN = 20


def _shift(sfc: Node) -> None:
    """Move the chart right and down so that nothing lies left of or above the margin (the
    drawing is centred on x = 0; editors expect positive coordinates)."""
    points = [p for p in _walk(sfc) if p.tag == "position"]
    if not points:
        return
    dx = MARGIN - min(int(p.attrs["x"]) for p in points)
    dy = MARGIN - min(int(p.attrs["y"]) for p in points)
    for p in points:
        p.attrs["x"] = str(int(p.attrs["x"]) + dx)
        p.attrs["y"] = str(int(p.attrs["y"]) + dy)


def _walk(n: Node) -> list[Node]:
    out, stack = [], [n]
    while stack:
        e = stack.pop()
        out.append(e)
        stack.extend(e.children)
    return out


def _n(v: float) -> str:
    """A length or a coordinate as the file holds it: a whole number of px."""
    return str(int(round(v)))


def _pos(e: Node, x: float, y: float) -> None:
    e.add("position", {"x": _n(x), "y": _n(y)})


def _rel(point: Node, origin: Point, pin: Point) -> None:
    point.add("relPosition", {"x": _n(pin[0] - origin[0]), "y": _n(pin[1] - origin[1])})
