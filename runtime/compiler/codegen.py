"""Compiles a Grafcet model into Python source and one scan function per grafcet.

The scan function ``scan(m, now, up)`` works on an instance's state list ``m`` (unpacked
into locals at the start and stored back at the end), ``now`` the monotonic time (ns) and
``up`` the time since the controller started (ns, for the clock bits). Instances share the
code and own their state list. The order of one scan is semantics.md's, per scan model.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from typing import Any

from runtime.compiler.program import Probe, Program, Slot, SlotKind, step_time_code
from runtime.errors import SoftplcError
from runtime.language import ast as A
from runtime.language.lexer import format_time
from runtime.language.model import Action, Grafcet, Qualifier, ScanModel, Step, Transition, VarKind
from runtime.language.typecheck import CLOCK_PERIOD_NS
from runtime.language.unparse import transition_text

T = A.Type
#: rounds of the stable-situation search before "unstable chart"
STABLE_MAX_ROUNDS = 100


class UnstableChart(SoftplcError, RuntimeError):
    """``scan: stable`` found no stable situation within STABLE_MAX_ROUNDS rounds."""

    def __init__(self, chart: str, cycle: list[str], steps: list[str] | None = None) -> None:
        steps = steps or []
        super().__init__(f"unstable chart {chart}: the search for a stable situation did not "
                         f"end after {STABLE_MAX_ROUNDS} rounds; cycle of steps "
                         f"{', '.join(steps)}; transitions still firing: {'; '.join(cycle)}")
        self.cycle = cycle  # the transitions fired in the last round, "src -> dst when c"
        self.steps = steps  # their source and target steps, file order


def _unstable(chart: str, names: list[str], steps: list[list[str]], order: list[str],
              fired: tuple[bool, ...]) -> UnstableChart:
    """Builds UnstableChart from the transitions fired in the last round (cold path)."""
    involved = {s for ss, f in zip(steps, fired, strict=True) if f for s in ss}
    return UnstableChart(chart, [n for n, f in zip(names, fired, strict=True) if f],
                         [s for s in order if s in involved])


def _idiv(a: int, b: int) -> int:
    """IEC integer division: truncates toward zero."""
    q = abs(a) // abs(b)
    return q if (a >= 0) == (b >= 0) else -q


def _imod(a: int, b: int) -> int:
    """IEC MOD: the sign follows the dividend."""
    return a - b * _idiv(a, b)


def min_timed(g: Grafcet, t: Transition) -> list[Step]:
    """The steps with a ``min`` time that ``t`` leaves: each source as written, and for a
    macro-step its exit step, down to a plain step (a macro-step's min counts too)."""
    out = []
    for name in t.sources:
        st = g.steps[name]
        while True:
            if st.min_ns:
                out.append(st)
            if st.macro is None:
                break
            st = g.steps[st.macro.exit]
    return out


def _ident(prefix: str, name: str) -> str:
    return f"{prefix}_{name}"


class _Emitter:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.level = 1

    def __call__(self, line: str) -> None:
        self.lines.append("    " * self.level + line)

    def indent(self) -> None:
        self.level += 1

    def dedent(self) -> None:
        self.level -= 1


class Compiler:
    """Generates the scan function of one grafcet."""

    def __init__(self, g: Grafcet) -> None:
        self.g = g
        self.slots: list[Slot] = []
        self.index: dict[str, int] = {}  # slot key -> index
        self.stored: dict[str, int] = {}  # local of a slot -> index
        self.edges: dict[int, int] = {}  # id(node) -> edge number
        self.edge_nodes: list[A.Unary] = []
        self.tmp = 0
        self.leaf = g.leaf_steps()
        self.macros = [s for s in g.steps.values() if s.macro is not None]
        self.stable = g.scan is ScanModel.STABLE
        self.codesys = g.scan is ScanModel.CODESYS

    # -- state layout ----------------------------------------------------------------
    def slot(self, key: str, local: str, init: Any, block: str | None = None,
             kind: SlotKind = SlotKind.INTERNAL, name: str = "",
             type_: A.Type | None = None) -> None:
        i = len(self.slots)
        self.index[key] = i
        self.stored[local] = i
        self.slots.append(Slot(key, local, init, block, kind, name, type_, i))

    def let(self, *targets: str, value: str) -> str:
        """``a = b = value``, where each state local is also stored into its slot
        (``a = m[i] = value``): a scan writes only what it changes, instead of packing
        every local back at its end (drawer tester: 0.91 us instead of 1.51 us a scan)."""
        parts = [f"{t} = m[{self.stored[t]}]" if t in self.stored else t for t in targets]
        return " = ".join([*parts, value])

    def add(self, target: str, delta: str) -> str:
        """``target += delta``, stored like ``let``."""
        return self.let(target, value=f"{target} + ({delta})")

    def layout(self) -> None:
        g = self.g
        for v in g.variables.values():
            if v.kind is VarKind.SYSTEM:
                continue
            self.slot(v.name, _ident("v", v.name), v.init, None, SlotKind.VARIABLE, v.name,
                      v.type)
        for s in g.steps.values():
            self.slot(f"{s.name}.X", _ident("x", s.name), s.initial or self._macro_initial(s),
                      None, SlotKind.STEP_X, s.name, T.BOOL)
            self.slot(f"{s.name}.T0", _ident("t0", s.name), 0, None, SlotKind.STEP_START,
                      s.name, T.TIME)
            self.slot(f"{s.name}.TK", _ident("tk", s.name), 0, None, SlotKind.STEP_LAST,
                      s.name, T.TIME)
        for name in g.timers:
            self.slot(name, _ident("b", name), None, "SeedTimer", SlotKind.BLOCK, name)
        for b in g.blocks.values():
            self.slot(b.name, _ident("b", b.name), None, b.kind, SlotKind.BLOCK, b.name)
        self.slot("#ct", "ct", 0, None, SlotKind.CLOCK, "", T.TIME)
        for key, local, init in (("#last", "lastnow", 0),
                                 ("#first", "first", True), ("#initpend", "initpend", True),
                                 ("#paused", "wp", False), ("#resetprev", "resetprev", False),
                                 ("#quitprev", "quitprev", False), ("#tipprev", "tipprev", True)):
            self.slot(key, local, init)
        if self.codesys:
            for t in g.transitions:
                self.slot(f"#pending{t.index}", f"pf{t.index}", False)
            for a in g.actions():  # Q of the last scan, for the final scan of L/D actions
                if a.body is not None and a.qualifier in (Qualifier.L, Qualifier.D):
                    self.slot(f"#cq{a.index}.F", f"cq{a.index}", False)
        for target, assocs in self.bool_targets().items():
            quals = {a.qualifier for a in assocs}
            if Qualifier.S in quals:
                self.slot(f"#S.{target}", _ident("s", target), False)
            for k, a in enumerate(assocs):
                if a.qualifier in (Qualifier.SD, Qualifier.SL, Qualifier.DS):
                    tag = f"{a.qualifier.value.lower()}{k}_{target}"
                    self.slot(f"#{tag}.F", f"f{tag}", False)
                    self.slot(f"#{tag}.T", f"t{tag}", 0)
        # edges: every RE/FE node of the chart
        for n in self._all_nodes():
            if isinstance(n, A.Unary) and n.op in ("RE", "FE"):
                k = len(self.edge_nodes)
                self.edges[id(n)] = k
                self.edge_nodes.append(n)
                self.slot(f"#edge{k}.prev", f"ep{k}", n.op == "RE")
                self.slot(f"#edge{k}", f"e{k}", False)

    def _macro_initial(self, s: Step) -> bool:
        return s.macro is not None and self.g.steps[s.macro.entry].initial

    def _all_nodes(self) -> Iterator[A.Node]:
        g = self.g
        roots: list[A.Node] = [st.node for st in g.pre]
        roots += [t.cond for t in g.transitions]
        for a in g.actions():
            roots += [x for x in (a.cond, a.event) if x is not None]
            roots += a.body or []
        roots += [st.node for st in g.post]
        for r in roots:
            yield from A.walk(r)

    def bool_targets(self) -> dict[str, list[Action]]:
        out: dict[str, list[Action]] = {}
        for a in self.g.actions():
            if a.target is not None:
                out.setdefault(a.target, []).append(a)
        return out

    # -- expressions -------------------------------------------------------------------
    def ref_local(self, kind: str, name: str) -> str:
        if kind == "var":
            return _ident("v", name)
        if kind == "X":
            return _ident("x", name)
        if kind == "T":
            return step_time_code(_ident("x", name), "ct", _ident("t0", name),
                                  _ident("tk", name))
        if kind == "block":
            return _ident("b", name)
        if kind == "edge":
            return f"e{name}"
        if kind == "first":
            return "first"
        raise AssertionError(kind)

    def ref_state(self, kind: str, name: str) -> str:
        """References into the state list, for explain's probes (evaluated between scans)."""
        ix = self.index
        if kind == "var":
            return f"m[{ix[name]}]"
        if kind == "X":
            return f"m[{ix[name + '.X']}]"
        if kind == "T":
            return step_time_code(f"m[{ix[name + '.X']}]", f"m[{ix['#ct']}]",
                                  f"m[{ix[name + '.T0']}]", f"m[{ix[name + '.TK']}]")
        if kind == "block":
            return f"m[{ix[name]}]"
        if kind == "edge":
            return f"m[{ix[f'#edge{name}']}]"
        if kind == "first":
            return f"m[{ix['#first']}]"
        raise AssertionError(kind)

    def ex(self, n: A.Node, ref: Callable[[str, str], str] | None = None) -> str:
        r = ref or self.ref_local
        e = self.ex
        if isinstance(n, A.Lit):
            if n.type is T.BOOL:
                return "True" if n.value else "False"
            return repr(n.value)
        if isinstance(n, A.Name):
            if n.name == "FirstScan":
                return r("first", "")
            if n.name in CLOCK_PERIOD_NS:
                p = CLOCK_PERIOD_NS[n.name]
                return f"(up % {p} < {p // 2})"
            return r("var", n.name)
        if isinstance(n, A.StepFlag):
            return r(n.flag, n.step)
        if isinstance(n, A.Member):
            return f"{r('block', n.obj)}.{n.member}"
        if isinstance(n, A.MethodCall):
            return f"{r('block', n.obj)}.{n.method.lower()}(now)"
        if isinstance(n, A.Unary):
            if n.op == "NOT":
                return f"(not {e(n.operand, ref)})"
            if n.op == "NEG":
                return f"(-{e(n.operand, ref)})"
            return r("edge", str(self.edges[id(n)]))
        if isinstance(n, A.Binary):
            lhs, rhs = e(n.left, ref), e(n.right, ref)
            op = n.op
            if op == "OR":
                return f"({lhs} or {rhs})"
            if op == "AND":
                return f"({lhs} and {rhs})"
            if op == "XOR":
                return f"({lhs} != {rhs})"
            if op == "DIV":
                if n.type is T.REAL:
                    return f"({lhs} / {rhs})"
                if T.REAL in (n.left.type, n.right.type):
                    return f"int({lhs} / {rhs})"
                return f"_idiv({lhs}, {rhs})"
            if op == "MOD":
                return f"_imod({lhs}, {rhs})"
            if op == "MUL" and n.type is T.TIME and T.REAL in (n.left.type, n.right.type):
                return f"int({lhs} * {rhs})"
            sym = {"ADD": "+", "SUB": "-", "MUL": "*", "EQ": "==", "NE": "!=", "LT": "<",
                   "LE": "<=", "GT": ">", "GE": ">="}[op]
            return f"({lhs} {sym} {rhs})"
        raise AssertionError(type(n))

    def sample_edges(self, out: _Emitter, roots: list[A.Node]) -> None:
        """Sample every edge below ``roots`` (inner edges first), once per scan."""
        found: list[A.Unary] = []
        for root in roots:
            for n in A.walk(root):
                if isinstance(n, A.Unary) and n.op in ("RE", "FE") and n not in found:
                    found.append(n)
        for n in reversed(found):
            k = self.edges[id(n)]
            cur = self.ex(n.operand)
            out(f"_c = {cur}")
            now = f"_c and not ep{k}" if n.op == "RE" else f"ep{k} and not _c"
            out(f"{self.let(f'e{k}', value=now)}; {self.let(f'ep{k}', value='_c')}")

    # -- statements --------------------------------------------------------------------
    def converted(self, vt: A.Type | None, value: A.Node) -> str:
        """``value`` as stored into a variable of type ``vt`` (bool -> 0/1, int -> real)."""
        code, et = self.ex(value), value.type
        if vt is T.INT and et is T.BOOL:
            return f"int({code})"
        if vt is T.REAL and et in (T.INT, T.BOOL):
            return f"float({code})"
        return code

    def stmt(self, out: _Emitter, s: A.Node) -> None:
        if isinstance(s, A.Assign):
            value = self.converted(s.target.type, s.value)
            out(self.let(_ident("v", s.target.name), value=value))
        elif isinstance(s, A.CallStmt):
            c = s.call
            if c.method == "Set":
                var = self.g.variables.get(c.obj)
                value = self.converted(var.type if var else None, c.args[0])
                out(f"if {self.ex(c.args[1])}: {self.let(_ident('v', c.obj), value=value)}")
            elif c.method == "Ini":
                out(f"{_ident('b', c.obj)}.ini(now, {self.ex(c.args[0])})")
            else:
                out(f"{_ident('b', c.obj)}.reset()")
        elif isinstance(s, A.FbCall):
            b = _ident("b", s.block)
            for arg, val in s.args:
                out(f"{b}.{arg} = {self.ex(val)}")
            out(f"{b}.update(now)")
        elif isinstance(s, A.If):
            for i, (cond, body) in enumerate(s.branches):
                out(f"{'if' if i == 0 else 'elif'} {self.ex(cond)}:")
                self.block(out, body)
            if s.orelse:
                out("else:")
                self.block(out, s.orelse)
        elif isinstance(s, A.Case):
            self.tmp += 1
            sel = f"_sel{self.tmp}"
            out(f"{sel} = {self.ex(s.selector)}")
            for i, (labels, body) in enumerate(s.arms):
                tests = " or ".join(f"{sel} == {lo}" if lo == hi else f"{lo} <= {sel} <= {hi}"
                                    for lo, hi in labels)
                out(f"{'if' if i == 0 else 'elif'} {tests}:")
                self.block(out, body)
            if s.orelse:
                out("else:" if s.arms else "if True:")
                self.block(out, s.orelse)
        elif isinstance(s, A.For):
            self.tmp += 1
            k = self.tmp
            v = _ident("v", s.var.name)
            out(f"_last{k} = {self.ex(s.last)}; _by{k} = {self.ex(s.step) if s.step else 1}")
            out(f"if _by{k} == 0: raise ZeroDivisionError('FOR loop with BY 0')")
            out(self.let(v, value=self.ex(s.first)))
            out(f"while ({v} <= _last{k}) if _by{k} > 0 else ({v} >= _last{k}):")
            self.block(out, s.body, extra=self.add(v, f"_by{k}"))
        else:  # pragma: no cover
            raise AssertionError(type(s))

    def block(self, out: _Emitter, body: list[A.Node], extra: str | None = None) -> None:
        out.indent()
        if not body and extra is None:
            out("pass")
        for s in body:
            self.stmt(out, s)
        if extra:
            out(extra)
        out.dedent()

    # -- chart pieces ------------------------------------------------------------------
    def fired_name(self, t: Transition) -> str:
        return f"pf{t.index}" if self.codesys else f"f{t.index}"

    def evaluate_transitions(self, out: _Emitter) -> None:
        g = self.g
        taken: dict[str, list[str]] = {}
        for t in g.transitions:
            f = self.fired_name(t)
            terms = [_ident("x", s) for s in t.src_steps]
            for st in min_timed(g, t):
                terms.append(f"(ct - {_ident('t0', st.name)}) >= {st.min_ns}")
            earlier = sorted({e for s in t.src_steps for e in taken.get(s, [])})
            terms += [f"not {e}" for e in earlier]
            terms.append(self.ex(t.cond))
            out(f"# {transition_text(t)}")
            out(self.let(f, value=" and ".join(terms)))
            for s in t.src_steps:
                taken.setdefault(s, []).append(f)

    def _leave(self, step: str) -> str:
        """Statements deactivating ``step``: its .T is kept, it is marked left."""
        x, t0, tk, lft = (_ident(p, step) for p in ("x", "t0", "tk", "l"))
        return (f"{self.let(x, value='False')}; {self.let(tk, value=f'ct - {t0}')}; "
                f"{self.let(lft, value='True')}")

    def _enter(self, step: str) -> str:
        """Statements activating ``step``: its .T restarts, it is marked entered."""
        x, t0, a = (_ident(p, step) for p in ("x", "t0", "a"))
        return (f"{self.let(x, value='True')}; {self.let(t0, value='ct')}; "
                f"{self.let(a, value='True')}")

    def apply_fired(self, out: _Emitter) -> None:
        """Deactivate sources, then activate targets, of the transitions that fired."""
        g = self.g
        for st in self.leaf:
            leaving = [self.fired_name(t) for t in g.transitions if st.name in t.src_steps]
            entering = [self.fired_name(t) for t in g.transitions if st.name in t.dst_steps]
            x, t0 = _ident("x", st.name), _ident("t0", st.name)
            if leaving and entering:
                out(f"if {' or '.join(leaving)}:")
                out.indent()
                out(f"if {' or '.join(entering)}: {self.let(t0, value='ct')}  "
                    "# rule 5: stays active, .T restarts")
                out(f"else: {self._leave(st.name)}")
                out.dedent()
                out(f"elif ({' or '.join(entering)}) and not {x}: {self._enter(st.name)}")
            elif leaving:
                out(f"if {' or '.join(leaving)}: {self._leave(st.name)}")
            elif entering:
                out(f"if ({' or '.join(entering)}) and not {x}: {self._enter(st.name)}")
        for m in self.macros:
            assert m.macro is not None
            x, t0, tk = (_ident(p, m.name) for p in ("x", "t0", "tk"))
            a, lft = _ident("a", m.name), _ident("l", m.name)
            inner = [_ident("x", s) for s in m.macro.steps if g.steps[s].macro is None]
            entering = [self.fired_name(t) for t in g.transitions
                        if m.name in self._entered_macros(t)]
            leaving = [self.fired_name(t) for t in g.transitions
                       if m.name in self._left_macros(t)]
            out(f"_nx = {' or '.join(inner)}")
            if entering:
                # entered: its .T restarts if it was inactive, or left and re-entered now
                again = f" or {' or '.join(leaving)}" if leaving else ""
                out(f"if ({' or '.join(entering)}) and (not {x}{again}):")
                out.indent()
                out(self.let(t0, value="ct"))
                out(f"if not {x}: {self.let(a, value='True')}")
                out.dedent()
            out(f"if {x} and not _nx: {self.let(tk, value=f'ct - {t0}')}; "
                f"{self.let(lft, value='True')}")
            out(self.let(x, value="_nx"))

    def _left_macros(self, t: Transition) -> set[str]:
        """The macro-steps that ``t`` leaves: its sources' exit chains."""
        out: set[str] = set()
        for name in t.sources:
            st = self.g.steps[name]
            while st.macro is not None:
                out.add(st.name)
                st = self.g.steps[st.macro.exit]
        return out

    def _entered_macros(self, t: Transition) -> set[str]:
        out: set[str] = set()
        for name in t.targets:
            st = self.g.steps[name]
            while st.macro is not None:
                out.add(st.name)
                st = self.g.steps[st.macro.entry]
        return out

    def to_initial(self, out: _Emitter, mark_entered: bool) -> None:
        """Situation = initial steps, every .T = 0."""
        for st in self.g.steps.values():
            x, t0, tk = (_ident(p, st.name) for p in ("x", "t0", "tk"))
            init = st.initial or self._macro_initial(st)
            line = (f"{self.let(x, value=str(init))}; {self.let(t0, value='ct')}; "
                    f"{self.let(tk, value='0')}")
            if mark_entered and init:
                line += f"; {self.let(_ident('a', st.name), value='True')}"
            out(line)
        if self.codesys:
            out("; ".join(self.let(f"pf{t.index}", value="False") for t in self.g.transitions)
                or "pass")

    def reset_stored(self, out: _Emitter) -> None:
        for s in self.slots:
            if s.key.startswith("#S.") or (s.key.startswith("#") and s.key.endswith(".F")):
                out(self.let(s.local, value="False"))

    # -- actions -------------------------------------------------------------------------
    def active(self, step: str) -> str:
        x = _ident("x", step)
        return f"({x} or {_ident('a', step)})" if self.stable else x

    def bool_action(self, out: _Emitter, target: str, assocs: list[Action]) -> None:
        out(f"# action control of {target}: " + "; ".join(
            f"{a.qualifier.value} in {a.step}" for a in assocs))
        terms: list[str] = []
        resets = [self.active(a.step) for a in assocs if a.qualifier is Qualifier.R]
        r = None
        if resets:
            r = "_r"
            out(f"_r = {' or '.join(resets)}")
        sets = [self.active(a.step) for a in assocs if a.qualifier is Qualifier.S]
        if sets:
            s = _ident("s", target)
            out(self.let(s, value=f"({s} or {' or '.join(sets)})" + (" and not _r" if r else "")))
            terms.append(s)
        for k, a in enumerate(assocs):
            q, st = a.qualifier, a.step
            x, t0 = _ident("x", st), _ident("t0", st)
            if q is Qualifier.N:
                terms.append(f"({x} and {self.ex(a.cond)})" if a.cond is not None else x)
            elif q is Qualifier.L:
                terms.append(f"({x} and ct - {t0} < {a.time_ns})")
            elif q is Qualifier.D:
                terms.append(f"({x} and ct - {t0} >= {a.time_ns})")
            elif q is Qualifier.P:
                terms.append(_ident("a", st))
            elif q in (Qualifier.SD, Qualifier.SL, Qualifier.DS):
                tag = f"{q.value.lower()}{k}_{target}"
                ff, tt = f"f{tag}", f"t{tag}"
                if q is Qualifier.DS:
                    out(f"if {x} and ct - {t0} >= {a.time_ns}: {self.let(ff, value='True')}")
                    terms.append(ff)
                else:
                    out(f"if {self.active(st)} and not {ff}: {self.let(ff, value='True')}; "
                        f"{self.let(tt, value='ct')}")
                    cmp = ">=" if q is Qualifier.SD else "<"
                    terms.append(f"({ff} and ct - {tt} {cmp} {a.time_ns})")
                if r:
                    out(f"if _r: {self.let(ff, value='False')}")
        value = " or ".join(terms) or "False"
        if r:
            value = f"not _r and ({value})"
        out(self.let(_ident("v", target), value=value))

    def statement_action(self, out: _Emitter, a: Action, final_scan: bool = False) -> None:
        """``if <the action's Q>: body``; with ``final_scan``, CODESYS's extra run of an IEC
        action whose step was left in the previous scan (Q = false)."""
        q, st = a.qualifier, a.step
        x, t0 = _ident("x", st), _ident("t0", st)
        ent, left = _ident("a", st), _ident("l", st)
        text = a.text.replace("\n", " ")
        label = f"{q.value if q is not Qualifier.EVENT else 'on'} in {st}: {text[:60]}"
        held = f"cq{a.index}" if self.codesys and q in (Qualifier.L, Qualifier.D) else None
        if final_scan:
            out(f"# final scan of {label}")
            # an L/D action runs once more only if it was running in the previous scan
            out(f"if {left} and {held}:" if held else f"if {left}:")
            self.block(out, a.body or [])
            return
        if q is Qualifier.N:
            cond = x
        elif q is Qualifier.L:
            cond = f"{x} and ct - {t0} < {a.time_ns}"
        elif q is Qualifier.D:
            cond = f"{x} and ct - {t0} >= {a.time_ns}"
        elif q in (Qualifier.P, Qualifier.P1):
            cond = ent
        elif q is Qualifier.P0:
            cond = left
        else:  # EVENT
            cond = f"{self.active(st)} and {self.ex(a.event)}"  # type: ignore[arg-type]
        out(f"# {label}")
        if held:
            out(self.let(held, value=cond))
            cond = held
        out(f"if {cond}:")
        self.block(out, a.body or [])

    def actions(self, out: _Emitter) -> None:
        g = self.g
        stmt_actions = [a for a in g.actions() if a.body is not None]
        targets = self.bool_targets()
        if self.codesys:
            for q in (Qualifier.P0, Qualifier.P1):
                for a in stmt_actions:
                    if a.qualifier is q:
                        self.statement_action(out, a)
            for target, assocs in targets.items():
                self.bool_action(out, target, assocs)
            for a in stmt_actions:
                if a.qualifier in (Qualifier.N, Qualifier.L, Qualifier.D, Qualifier.P):
                    self.statement_action(out, a, final_scan=True)
            for a in stmt_actions:
                if a.qualifier not in (Qualifier.P0, Qualifier.P1):
                    self.statement_action(out, a)
        else:
            for target, assocs in targets.items():
                self.bool_action(out, target, assocs)
            for a in stmt_actions:
                self.statement_action(out, a)
        supervised = [s for s in g.steps.values() if s.max_ns is not None]  # macro-steps too
        if supervised:
            out("if v_SFCEnableLimit and not v_SFCError:")
            out.indent()
            for i, s in enumerate(supervised):
                x, t0 = _ident("x", s.name), _ident("t0", s.name)
                out(f"{'if' if i == 0 else 'elif'} {x} and ct - {t0} > {s.max_ns}: "
                    f"{self.let('v_SFCError', value='True')}; "
                    f"{self.let('v_SFCErrorStep', value=repr(s.name))}")
            out.dedent()

    # -- the scan function ---------------------------------------------------------------
    def generate(self) -> str:
        g = self.g
        self.layout()
        out = _Emitter()
        locals_ = ", ".join(s.local for s in self.slots)
        head = [f"# softplc: generated scan of grafcet {g.name} ({g.path})",
                f"# scan model: {g.scan.value}; {len(self.leaf)} steps, "
                f"{len(g.transitions)} transitions, {len(self.slots)} state slots",
                "def scan(m, now, up):"]
        out(f"{locals_}, = m")
        out("# chart clock: advances unless the chart was paused during the last interval")
        L = self.let  # noqa: N806 - short: many emitted lines
        out(f"if first: {L('ct', value='0')}")
        out(f"elif not wp: {self.add('ct', 'now - lastnow')}")
        out(L("lastnow", value="now"))
        steps = list(g.steps.values())
        out(" = ".join(_ident("a", s.name) for s in steps) + " = False")
        out(" = ".join(_ident("l", s.name) for s in steps) + " = False")
        if g.pre:
            out("# 1. pre equations")
            for s in g.pre:
                self.sample_edges(out, [s.node])
                self.stmt(out, s.node)
        out("# 2. chart flags (one test when none is set: the usual scan)")
        out("frozen = paused = tip = False; run = True")
        out("if v_SFCInit or initpend or v_SFCReset or resetprev or v_SFCQuitError or "
            "quitprev or v_SFCPause or v_SFCTip or tipprev:")
        out.indent()
        out("if v_SFCInit:")
        out.indent()
        self.to_initial(out, mark_entered=False)
        self.reset_stored(out)
        out(f"{L('v_SFCError', 'v_SFCPause', 'v_SFCQuitError', value='False')}; "
            f"{L('v_SFCErrorStep', value=repr(''))}")
        out(f"{L('initpend', 'frozen', value='True')}; run = False")
        out.dedent()
        out("elif initpend:  # start-up, or SFCInit fell: the initial steps are activated")
        out.indent()
        out(f"{L('initpend', value='False')}; frozen = True")
        self.to_initial(out, mark_entered=True)
        out.dedent()
        out("elif v_SFCReset:")
        out.indent()
        self.reset_stored(out)
        out(f"{L('v_SFCError', value='False')}; {L('v_SFCErrorStep', value=repr(''))}  "
            "# SFCReset acknowledges an error")
        self.to_initial(out, mark_entered=False)
        out("if not resetprev:")
        out.indent()
        out("; ".join(L(_ident("a", s.name), value="True") for s in steps
                      if s.initial or self._macro_initial(s)))
        out.dedent()
        out("frozen = True")
        out.dedent()
        out("else:")
        out.indent()
        out(f"if v_SFCQuitError: {L('v_SFCError', value='False')}; "
            f"{L('v_SFCErrorStep', value=repr(''))}; frozen = paused = True")
        out("elif quitprev:  # SFCQuitError fell: the active steps' times restart")
        out.indent()
        for st in steps:
            out(f"if {_ident('x', st.name)}: {L(_ident('t0', st.name), value='ct')}")
        out.dedent()
        out("if v_SFCPause: frozen = paused = True")
        out.dedent()
        out(f"{L('resetprev', value='v_SFCReset')}; {L('quitprev', value='v_SFCQuitError')}")
        out(f"tip = v_SFCTip and not tipprev; {L('tipprev', value='v_SFCTip')}")
        out.dedent()
        if self.codesys:
            if g.transitions:
                out("# 3. CODESYS: the situation decided by the last scan becomes current "
                    "(held while paused)")
                pending = " or ".join(f"pf{t.index}" for t in g.transitions)
                out(f"if not frozen and ({pending}):")
                out.indent()
                self.apply_fired(out)
                out.dedent()
            self.actions_section(out)
            self.evolution_section(out)
        else:
            self.evolution_section(out)
            self.actions_section(out)
        if g.post:
            out("# 6. post equations")
            for s in g.post:
                self.sample_edges(out, [s.node])
                self.stmt(out, s.node)
        out(f"{L('first', value='False')}; {L('wp', value='paused')}")
        return "\n".join(head + out.lines) + "\n"

    def evolution_section(self, out: _Emitter) -> None:
        g = self.g
        if self.codesys:
            out("# 5b. CODESYS: the transitions decide the next scan's situation")
        else:
            out("# 3. evolution")
        self.sample_edges(out, [t.cond for t in g.transitions])
        if not g.transitions:
            return
        if self.codesys:
            out("if not frozen and (not v_SFCTipMode or tip):")
            out.indent()
            self.evaluate_transitions(out)
            out.dedent()
            out("elif not paused:  # a pending evolution waits for the end of a pause")
            out.indent()
            out(self.let(*(f"pf{t.index}" for t in g.transitions), value="False"))
            out.dedent()
            return
        fired = " or ".join(f"f{t.index}" for t in g.transitions)
        out("if not frozen and (not v_SFCTipMode or tip):")
        out.indent()
        if self.stable:
            out("rounds = 0")
            out("while True:")
            out.indent()
            self.evaluate_transitions(out)
            out(f"if not ({fired}): break")
            self.apply_fired(out)
            out("rounds += 1")
            trans_edges = sorted({self.edges[id(n)] for t in g.transitions
                                  for n in A.walk(t.cond)
                                  if isinstance(n, A.Unary) and n.op in ("RE", "FE")})
            if trans_edges:
                out("if rounds == 1:  # edges are true in the first round only")
                out.indent()
                out(self.let(*(f"e{k}" for k in trans_edges), value="False"))
                out.dedent()
            out(f"if rounds > {STABLE_MAX_ROUNDS}:")
            out.indent()
            names = [transition_text(t) for t in g.transitions]
            steps = [[*t.src_steps, *t.dst_steps] for t in g.transitions]
            flags = ", ".join(f"f{t.index}" for t in g.transitions)
            out(f"raise _Unstable({g.name!r}, {names!r}, {steps!r}, "
                f"{[s.name for s in self.leaf]!r}, ({flags},))")
            out.dedent()
            out.dedent()
        else:
            self.evaluate_transitions(out)
            out(f"if {fired}:")
            out.indent()
            self.apply_fired(out)
            out.dedent()
        out.dedent()

    def actions_section(self, out: _Emitter) -> None:
        g = self.g
        out("# 4-5. actions on the new situation, then supervision")
        roots: list[A.Node] = []
        for a in g.actions():
            roots += [x for x in (a.cond, a.event) if x is not None]
            roots += a.body or []
        self.sample_edges(out, roots)
        out("if run and not paused:")
        out.indent()
        before = len(out.lines)
        self.actions(out)
        if len(out.lines) == before:
            out("pass")
        out.dedent()
        targets = list(self.bool_targets())
        if targets:
            out("elif not paused:  # SFCInit: no action executes, bool targets are off")
            out.indent()
            out(self.let(*(_ident("v", t) for t in targets), value="False"))
            out.dedent()

    def probes(self) -> dict[int, list[Probe]]:
        """Sub-terms of every transition condition, compiled against the state list."""
        out: dict[int, list[Probe]] = {}
        env = {"_idiv": _idiv, "_imod": _imod}

        def visit(n: A.Node, depth: int, terms: list[tuple[A.Node, int]]) -> None:
            terms.append((n, depth))
            if isinstance(n, A.Binary) and n.op in ("AND", "OR", "XOR"):
                visit(n.left, depth + 1, terms)
                visit(n.right, depth + 1, terms)
            elif isinstance(n, A.Unary) and n.op == "NOT":
                visit(n.operand, depth + 1, terms)

        for t in self.g.transitions:
            terms: list[tuple[A.Node, int]] = []
            visit(t.cond, 0, terms)
            lst = []
            for n, depth in terms:
                code = self.ex(n, self.ref_state)
                fn = eval(f"lambda m, now, up: {code}", dict(env))  # noqa: S307 - our own code
                lst.append(Probe(t.text[n.start:n.end], depth, fn))
            out[t.index] = lst
        return out


def compile_grafcet(g: Grafcet) -> Program:
    """Compile ``g`` into a Program (source, scan function, state layout)."""
    c = Compiler(g)
    source = c.generate()
    digest = hashlib.sha1(source.encode()).hexdigest()[:8]
    env: dict[str, Any] = {"_idiv": _idiv, "_imod": _imod, "_Unstable": _unstable}
    code = compile(source, f"<grafcet {g.name} {digest}>", "exec")
    exec(code, env)  # noqa: S102 - generated from the checked model
    return Program(g, source, env["scan"], c.slots, c.probes())


__all__ = ["Program", "Slot", "SlotKind", "Probe", "compile_grafcet", "UnstableChart",
           "format_time"]
