"""Name resolution and implicit typing of expressions and statements (seed 000 rules).

``+`` and ``*``/``·`` are logical between two bools and arithmetic otherwise (the node's
``op`` is rewritten to OR/AND for the compiler); bools count as 0/1 in arithmetic; the
literals 0 and 1 are bool constants where a bool is expected. Between a bool and a 0/1
literal (``iA + 1``) ``+``/``*`` take the type the context wants: arithmetic where a number
is wanted (an operand of arithmetic or of a comparison, a value for a numeric variable),
logical otherwise. Temporaries are names that start with ``t`` and a capital letter,
assigned somewhere in the program and typed by their first assignment in file order.
"""

from __future__ import annotations

from collections.abc import Callable

from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.model import Grafcet, Variable, VarKind
from runtime.language.signatures import FB_MEMBERS, TIMER_METHODS

T = A.Type
NUMERIC = (T.INT, T.REAL)
#: operators written with the seed's + and · (and *): logical or arithmetic by type
_PLUS, _TIMES = ("+",), ("*", "·", "∙", "⋅")

FLAGS_BOOL = ("SFCInit", "SFCReset", "SFCPause", "SFCError", "SFCEnableLimit",
              "SFCQuitError", "SFCTipMode", "SFCTip")
FLAGS_STRING = ("SFCErrorStep", "SFCCurrentStep")
SYSTEM_BOOL = ("FirstScan", "Clock_10Hz", "Clock_5Hz", "Clock_2Hz", "Clock_1Hz", "Clock_0_5Hz")
#: clock bit -> period in nanoseconds (50 % duty, from the controller's start)
CLOCK_PERIOD_NS = {"Clock_10Hz": 100_000_000, "Clock_5Hz": 200_000_000,
                   "Clock_2Hz": 500_000_000, "Clock_1Hz": 1_000_000_000,
                   "Clock_0_5Hz": 2_000_000_000}


WRITABLE_FLAGS = ("SFCInit", "SFCReset", "SFCPause", "SFCEnableLimit", "SFCQuitError",
                  "SFCTipMode", "SFCTip", "SFCError")


class TempUnknown(Exception):
    """A temporary read before its type is known (first inference pass only)."""


def looks_temporary(name: str) -> bool:
    """Seed 000: temporaries are named with a 't' prefix (tParo, tAveriaAbrir)."""
    return len(name) > 1 and name[0] == "t" and (name[1].isupper() or name[1] in "_0123456789")


def _seed_op(n: A.Binary) -> str | None:
    """ADD or MUL for a node written with the seed's ``+`` or ``·``/``*``, else None."""
    if n.text in _PLUS:
        return "ADD"
    if n.text in _TIMES:
        return "MUL"
    return None


def ambiguous(n: A.Node) -> bool:
    """A seed ``+``/``·`` typed logical only because of a 0/1 literal (``iA + 1``): it turns
    arithmetic where a number is wanted."""
    if not (isinstance(n, A.Binary) and n.op in ("OR", "AND") and _seed_op(n)):
        return False
    return any((isinstance(x, A.Lit) and x.bool_like) or ambiguous(x)
               for x in (n.left, n.right))


class Checker:
    """Types the expressions and statements of one grafcet, creating its temporaries.

    It annotates the syntax trees in place: each node's ``type``, the seed ``+``/``·``
    rewritten to OR/AND or ADD/MUL, a 0/1 literal's value as bool or int. Only the chart
    loader runs it, on trees it has just parsed, before ``load_grafcet`` caches and shares
    the Grafcet; nothing types a cached tree again (the compiler and the checker only read
    the annotations)."""

    def __init__(self, g: Grafcet) -> None:
        self.g = g
        self.temps_pending: dict[str, Loc] = {}  # temporaries assigned, type not yet known
        self.strict = False
        self.locate: Callable[[int], Loc] = lambda o: g.loc

    def err(self, node: A.Node | int, msg: str) -> SourceError:
        off = node if isinstance(node, int) else node.start
        return SourceError(self.locate(off), msg)

    def names(self) -> list[str]:
        return [*self.g.variables, *self.g.steps, *self.g.timers, *self.g.blocks]

    # -- expressions ---------------------------------------------------------------
    def expr(self, n: A.Node) -> A.Type:
        t = self._expr(n)
        n.type = t
        return t

    def numeric(self, n: A.Node) -> A.Type:
        """``n`` is wanted as a number: an ambiguous ``iA + 1`` becomes arithmetic."""
        if ambiguous(n):
            assert isinstance(n, A.Binary)
            n.op = _seed_op(n)  # type: ignore[assignment]
            for side in (n.left, n.right):
                if isinstance(side, A.Lit) and side.bool_like:
                    side.type, side.value = T.INT, int(side.value)
                else:
                    self.numeric(side)
            n.type = T.INT
        assert n.type is not None
        return n.type

    def want_bool(self, n: A.Node, what: str = "a bool") -> None:
        t = self.expr(n)
        if t is T.BOOL:
            return
        if isinstance(n, A.Lit) and n.bool_like:
            n.type = T.BOOL
            n.value = bool(n.value)
            return
        raise self.err(n, f"type error: expected {what}, found {t} "
                          f"'{self._text(n)}'")

    def _text(self, n: A.Node) -> str:
        return self.src[n.start:n.end]

    def _expr(self, n: A.Node) -> A.Type:
        if isinstance(n, A.Lit):
            if n.bool_like:  # typed afresh: a bool constant only where a bool is wanted
                n.value = int(n.value)
            return n.lit_type
        if isinstance(n, A.Name):
            return self._name(n)
        if isinstance(n, A.StepFlag):
            if n.step not in self.g.steps:
                what = ""
                if n.step in self.g.variables:
                    what = f" ('{n.step}' is a variable, not a step)"
                raise self.err(n, f"unknown step '{n.step}'{what}"
                                  f"{suggest(n.step, self.g.steps)}")
            return T.BOOL if n.flag == "X" else T.TIME
        if isinstance(n, A.Member):
            blk = self.g.blocks.get(n.obj)
            if blk is None:
                if n.obj in self.g.timers:
                    raise self.err(n, f"expected a call {n.obj}.{n.member}() of timer "
                                      f"'{n.obj}', found {n.obj}.{n.member}")
                if n.obj in self.g.steps:
                    raise self.err(n, f"step '{n.obj}' has only .X and .T, found "
                                      f"'.{n.member}'")
                raise self.err(n, f"unknown function block '{n.obj}'"
                                  f"{suggest(n.obj, self.g.blocks)}{self._declare_block(n.obj)}")
            members = FB_MEMBERS[blk.kind]
            if n.member not in members:
                raise self.err(n, f"{blk.kind} '{n.obj}' has no member '{n.member}': expected "
                                  f"one of {' '.join(members)}")
            return members[n.member][0]
        if isinstance(n, A.MethodCall):
            return self._method(n, as_statement=False)
        if isinstance(n, A.Unary):
            if n.op in ("NOT", "RE", "FE"):
                what = "postfix '" if n.text == "'" else n.text
                self.want_bool(n.operand, f"a bool operand of {what}")
                return T.BOOL
            self.expr(n.operand)  # NEG
            t = self.numeric(n.operand)
            if t is T.BOOL:
                return T.INT
            if t in (*NUMERIC, T.TIME):
                return t
            raise self.err(n, f"type error: expected a number or a time after '-', found {t}")
        if isinstance(n, A.Binary):
            return self._binary(n)
        raise self.err(n, "expected an expression")  # pragma: no cover

    def _declare_block(self, name: str) -> str:
        """Where an unknown block would be declared: the chart's ``blocks:`` mapping (a
        type guessed from the name's prefix, TON otherwise)."""
        kinds = sorted(FB_MEMBERS, key=len, reverse=True)  # CTUD before CTU
        kind = next((k for k in kinds if name.upper().startswith(k.replace("_", ""))), "TON")
        return (f": declare it in the chart's mapping of blocks (blocks: {{{name}: "
                f"{kind}}})")

    def _name(self, n: A.Name) -> A.Type:
        v = self.g.variables.get(n.name)
        if v is not None:
            if v.type is T.STRING:
                raise self.err(n, f"'{n.name}' is a string flag: it can be read by the console "
                                  "and the trace only")
            return v.type
        if n.name in self.temps_pending:
            if self.strict:
                raise self.err(n, f"cannot decide the type of temporary '{n.name}': assign it "
                                  "from an expression of known type")
            raise TempUnknown(n.name)
        if n.name in self.g.steps:
            raise self.err(n, f"step '{n.name}' is not a variable: write {n.name}.X (active) or "
                              f"{n.name}.T (time active)")
        if n.name in self.g.timers:
            raise self.err(n, f"timer '{n.name}' is read with {n.name}.End() or {n.name}.Val()")
        if n.name in self.g.blocks:
            raise self.err(n, f"function block '{n.name}' is read through its outputs, e.g. "
                              f"{n.name}.Q")
        raise self.err(n, f"unknown variable '{n.name}'{suggest(n.name, self.names())}")

    def _binary(self, n: A.Binary) -> A.Type:
        op = n.op = _seed_op(n) or n.op  # typed afresh on every pass
        if op in ("OR", "XOR", "AND"):
            self.want_bool(n.left, f"a bool operand of {n.text}")
            self.want_bool(n.right, f"a bool operand of {n.text}")
            return T.BOOL
        lt, rt = self.expr(n.left), self.expr(n.right)
        lb = lt is T.BOOL or (isinstance(n.left, A.Lit) and n.left.bool_like)
        rb = rt is T.BOOL or (isinstance(n.right, A.Lit) and n.right.bool_like)
        if op in ("ADD", "MUL") and lb and rb and T.BOOL in (lt, rt):
            for side in (n.left, n.right):
                if isinstance(side, A.Lit):
                    side.type, side.value = T.BOOL, bool(side.value)
            n.op = "OR" if op == "ADD" else "AND"
            return T.BOOL
        if op in ("EQ", "NE", "LT", "LE", "GT", "GE"):
            lt, rt = self.numeric(n.left), self.numeric(n.right)
            if (lt is T.TIME) != (rt is T.TIME):
                bad, good = (n.left, n.right) if rt is T.TIME else (n.right, n.left)
                raise self.err(bad, f"type error: expected a time to compare with time "
                                    f"'{self._text(good)}', found {bad.type} "
                                    f"'{self._text(bad)}'")
            return T.BOOL
        # arithmetic
        lt, rt = self.numeric(n.left), self.numeric(n.right)
        a = T.INT if lt is T.BOOL else lt
        b = T.INT if rt is T.BOOL else rt
        if a is T.TIME or b is T.TIME:
            if op in ("ADD", "SUB") and a is b:
                return T.TIME
            if op == "MUL" and {a, b} <= {T.TIME, T.INT, T.REAL} and (a is T.TIME) != (
                    b is T.TIME):
                return T.TIME
            if op == "DIV" and a is T.TIME and b in NUMERIC:
                return T.TIME
            raise self.err(n, f"type error: expected numbers, or times (+ -) or a time and a "
                              f"number (* /) for '{n.text}', found {lt} "
                              f"'{self._text(n.left)}' and {rt} '{self._text(n.right)}'")
        if op == "MOD" and (a is T.REAL or b is T.REAL):
            bad = n.left if a is T.REAL else n.right
            raise self.err(bad, f"type error: expected integers for MOD, found real "
                                f"'{self._text(bad)}'")
        return T.REAL if T.REAL in (a, b) else T.INT

    def _method(self, n: A.MethodCall, as_statement: bool) -> A.Type:
        m = n.method
        if m == "Set":
            if not as_statement:
                raise self.err(n, f"expected a value, found the statement "
                              f"{n.obj}.Set(value, condition)")
            target = A.Name(n.start, n.start + len(n.obj), n.obj)
            if len(n.args) != 2:
                raise self.err(n, f"expected 2 arguments (value, condition) for {n.obj}.Set, "
                                  f"found {len(n.args)}")
            if n.obj not in self.g.variables and n.obj in self.temps_pending:
                value = n.args[0]  # a temporary typed here: Set(1, c) latches a bool
                t = T.BOOL if isinstance(value, A.Lit) and value.bool_like else self.expr(value)
                self._new_temp(n.obj, t)
            vt = self._target_type(target)
            self._assignable(vt, n.args[0], n.obj)
            self.want_bool(n.args[1], "a bool condition in Set")
            return vt
        if n.obj not in self.g.timers:
            if m in TIMER_METHODS:
                declared = ", ".join([*self.g.timers, n.obj])
                raise self.err(n, f"unknown timer '{n.obj}'{suggest(n.obj, self.g.timers)}: "
                                  f"declare it in the chart's list of timers (timers: "
                                  f"[{declared}])")
            raise self.err(n, f"unknown method '{m}': expected Ini End Reset Val (timers) or "
                              "Set (variables)")
        if m not in TIMER_METHODS:
            raise self.err(n, f"timer '{n.obj}' has no method '{m}': expected Ini End Reset Val")
        want, result, statement = TIMER_METHODS[m]
        if len(n.args) != want:
            raise self.err(n, f"expected {want} argument(s) for {n.obj}.{m}, found "
                              f"{len(n.args)}")
        if statement and not as_statement:
            raise self.err(n, f"expected a value, found the statement {n.obj}.{m}(): "
                              "call it on its own")
        if not statement and as_statement:
            raise self.err(n, f"expected a statement, found the value {n.obj}.{m}(): use it "
                              "in an expression")
        if m == "Ini":
            t = self.expr(n.args[0])
            if t is not T.TIME:
                raise self.err(n.args[0], f"type error: expected a time for {n.obj}.Ini, found "
                                          f"{t} '{self._text(n.args[0])}'")
        return result

    # -- statements ----------------------------------------------------------------
    def _target_type(self, target: A.Name) -> A.Type:
        v = self.g.variables.get(target.name)
        if v is None:
            if target.name in self.temps_pending and not self.strict:
                raise TempUnknown(target.name)
            return self._name(target)
        if v.kind is VarKind.INPUT:
            raise self.err(target, f"expected an output, memory or temporary to assign, found "
                                   f"input '{v.name}' (inputs are read-only)")
        if v.kind is VarKind.SYSTEM or (v.kind is VarKind.FLAG and v.name not in
                                         WRITABLE_FLAGS):
            raise self.err(target, f"expected an output, memory or temporary to assign, found "
                                   f"{v.kind.value} '{v.name}' (read-only)")
        return v.type

    def _assignable(self, vt: A.Type, value: A.Node, name: str) -> None:
        if vt is T.BOOL:
            self.want_bool(value, f"a bool value for '{name}'")
            return
        self.expr(value)
        t = self.numeric(value) if vt in NUMERIC else value.type
        assert t is not None
        ok = t is vt or (vt is T.INT and t is T.BOOL) or (vt is T.REAL and t in (T.INT,
                                                                                T.BOOL))
        if not ok:
            article = "an" if vt is T.INT else "a"
            raise self.err(value, f"type error: expected {article} {vt} value for '{name}', "
                                  f"found {t} '{self._text(value)}'")

    def stmts(self, body: list[A.Node], loop_vars: tuple[str, ...] = ()) -> None:
        for s in body:
            self.stmt(s, loop_vars)

    def stmt(self, s: A.Node, loop_vars: tuple[str, ...] = ()) -> None:
        if isinstance(s, A.Assign):
            name = s.target.name
            if name in loop_vars:
                raise self.err(s.target, f"the FOR loop must not write its variable '{name}'")
            if name not in self.g.variables and name in self.temps_pending:
                t = self.expr(s.value)  # may raise TempUnknown in the first pass
                self._new_temp(name, t)
            vt = self._target_type(s.target)
            s.target.type = vt
            self._assignable(vt, s.value, name)
        elif isinstance(s, A.CallStmt):
            if s.call.obj in loop_vars and s.call.method == "Set":
                raise self.err(s, f"the FOR loop must not write its variable '{s.call.obj}'")
            self._method(s.call, as_statement=True)
        elif isinstance(s, A.FbCall):
            blk = self.g.blocks.get(s.block)
            if blk is None:
                raise self.err(s, f"unknown function block '{s.block}'"
                                  f"{suggest(s.block, self.g.blocks)}"
                                  f"{self._declare_block(s.block)}")
            members = FB_MEMBERS[blk.kind]
            for arg, val in s.args:
                if arg not in members or not members[arg][1]:
                    ins = [k for k, (_, i) in members.items() if i]
                    raise self.err(val, f"{blk.kind} '{s.block}' has no input '{arg}': expected "
                                        f"one of {' '.join(ins)}")
                self._assignable(members[arg][0], val, f"{s.block}.{arg}")
        elif isinstance(s, A.If):
            for cond, body in s.branches:
                self.want_bool(cond, "a bool IF condition")
                self.stmts(body, loop_vars)
            self.stmts(s.orelse, loop_vars)
        elif isinstance(s, A.Case):
            self.expr(s.selector)
            t = self.numeric(s.selector)
            if t not in (T.INT, T.BOOL):
                raise self.err(s.selector, f"type error: expected an int CASE selector, found "
                                           f"{t} '{self._text(s.selector)}'")
            for _, body in s.arms:
                self.stmts(body, loop_vars)
            self.stmts(s.orelse, loop_vars)
        elif isinstance(s, A.For):
            name = s.var.name
            if name not in self.g.variables and name in self.temps_pending:
                self._new_temp(name, T.INT)
            vt = self._target_type(s.var)
            if vt is not T.INT:
                raise self.err(s.var, f"type error: expected an int FOR variable, found {vt} "
                                      f"'{name}'")
            s.var.type = T.INT
            for part in (s.first, s.last, s.step):
                if part is not None:
                    self.expr(part)
                    t = self.numeric(part)
                    if t not in (T.INT, T.BOOL):
                        raise self.err(part, f"type error: expected int FOR bounds, found {t} "
                                             f"'{self._text(part)}'")
            by = s.step
            while isinstance(by, A.Unary) and by.op == "NEG":
                by = by.operand
            if isinstance(by, A.Lit) and not by.value and s.step is not None:
                raise self.err(s.step, "expected a non-zero BY step (a scan must always end), "
                                       f"found '{self._text(s.step)}'")
            self.stmts(s.body, (*loop_vars, name))
        else:  # pragma: no cover
            raise self.err(s, "expected a statement")

    def _new_temp(self, name: str, t: A.Type) -> None:
        loc = self.temps_pending.pop(name)
        self.g.variables[name] = Variable(name, VarKind.TEMP, t, _zero(t), loc)

    # -- driving -------------------------------------------------------------------
    def run(self, units: list[tuple[str, str, Callable[[int], Loc], object]]) -> None:
        """Type every unit: (kind, source text, locate, parsed) with kind expr|bool|stmts.

        Two passes: the first infers temporaries' types where their first assignment can be
        typed; the second checks everything strictly.
        """
        for strict in (False, True):
            self.strict = strict
            for _ in range(3 if not strict else 1):
                for kind, src, locate, parsed in units:
                    self.src, self.locate = src, locate
                    try:
                        if kind == "bool":
                            self.want_bool(parsed)  # type: ignore[arg-type]
                        elif kind == "stmts":
                            self.stmts(parsed)  # type: ignore[arg-type]
                        else:
                            self.expr(parsed)  # type: ignore[arg-type]
                    except TempUnknown:
                        if strict:  # pragma: no cover - strict mode raises SourceError
                            raise
                if not self.temps_pending:
                    break


def _zero(t: A.Type) -> object:
    return {T.BOOL: False, T.INT: 0, T.REAL: 0.0, T.TIME: 0, T.STRING: ""}[t]
