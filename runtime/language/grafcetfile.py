"""Loading grafcet files into the typed model, with errors as FILE:LINE:COL.

Plant files are loaded by runtime.language.plantfile, which uses this module for their charts.
Without a list of diagnostics the loader raises the first error; with one, it records the
rule errors of seed 000 that it can go on after (G101 no initial step: the first step is
taken as initial; G105 and G106 in actions: the action is left out) and raises the others.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from runtime.errors import Diagnostic, Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.lexer import KEYWORDS, is_name
from runtime.language.model import (
    IEC_TYPES,
    Action,
    Block,
    Grafcet,
    Macro,
    Qualifier,
    ScanModel,
    Statement,
    Step,
    Transition,
    Variable,
    VarKind,
)
from runtime.language.parser import parse_action, parse_expression, parse_statements
from runtime.language.shape import (
    DESCRIPTION,
    TIME,
    Bool,
    Choice,
    Def,
    Doc,
    Int,
    Key,
    ListOf,
    MapOf,
    Number,
    Ref,
    Section,
    Text,
    Time,
    any_of,
    description_text,
    expect_type,
    free_text,
    one_of,
    time_value,
    yaml11_bool_note,
)
from runtime.language.signatures import FB_MEMBERS
from runtime.language.typecheck import (
    FLAGS_BOOL,
    FLAGS_STRING,
    SYSTEM_BOOL,
    Checker,
    looks_temporary,
)
from runtime.language.yamlsrc import YList, YMap, YStr, load_yaml, synthetic_str

T = A.Type
TYPE_NAMES = {"bool": T.BOOL, "int": T.INT, "real": T.REAL, "time": T.TIME}

# -- the shape of a grafcet file (runtime/language/shape.py): the loader's key lists, and
# -- configs/schema/grafcet.schema.json generated from them
_TYPE = Choice(tuple(TYPE_NAMES))
_IEC_TYPE = Choice(tuple(n for names in IEC_TYPES.values() for n in names))
_IEC_DOC = ("The IEC 61131-3 type a PLCopen export declares (INT, DINT, REAL ...: one that "
            "fits the variable's type; without it LINT for int, LREAL for real). softplc "
            "import writes it; the runtime computes as the language's type whatever it says "
            "(no bounds, no wrap-around).")
#: a typed signal's mapping: ``{tTemp: {type: int, description: ...}}``
SIGNAL_SPEC = Section((
    Key("type", _TYPE, "The signal's type (default bool)."),
    Key("description", DESCRIPTION, "What the signal means (one line)."),
    Key("iec_type", _IEC_TYPE, _IEC_DOC),
))
SIGNAL = Def("signal", one_of(
    Doc(Text(), "A bool signal's name (iParo, oAbrir)."),
    MapOf(any_of(Doc(_TYPE, "The signal's type."), SIGNAL_SPEC), min_properties=1,
          max_properties=1)),
    "A signal: a name (bool), or a one-key mapping {name: type} for a typed signal "
    "({tTemperatura: int}), or {name: {type: int, description: ...}}.")
INITIAL = Def("initial", any_of(Bool(), Number(),
                                Choice(("TRUE", "FALSE", "true", "false", "True", "False")),
                                TIME),
              "Initial value; its form gives the type: false/true -> bool, 0 -> int, 0.0 -> "
              "real, a time (\"0s\", T#5s) -> time.")
#: a memory variable's mapping: ``{init: 0, retain: true}``
MEMORY_SPEC = Section((
    Key("init", INITIAL),
    Key("retain", Bool(), "Survives restart and power loss (written to the plant's retain "
                          "file)."),
    Key("renamed_from", Text(), "The variable's former name, when an edit renames it: online "
                                "change then carries its running value to the new name."),
    Key("description", DESCRIPTION, "What the variable means (one line), shown by the "
                                    "console, OPC UA and draw."),
    Key("iec_type", _IEC_TYPE, _IEC_DOC),
))
STATEMENTS = Def("statements", one_of(Text(), ListOf(Text())),
                 "Statements: one string, or a list of strings run in order. Assignments "
                 "'x := expr', 'sX.Set(v, cond)', 'timeX.Ini(10s)', block calls 'tonX(IN := "
                 "a, PT := 5s)', IF/CASE/FOR (ST). Quote texts that hold ': ' or start with a "
                 "YAML indicator, or use a block scalar '|'.")
ACTIONS = Def("actions", one_of(Text(), ListOf(Text())),
              "The step's actions, one string each: '[QUALIFIER [TIME]] BODY [if CONDITION]' "
              "or 'on EVENT do STATEMENTS'. Qualifiers N S R L D P P1 P0 DS SD SL (L D DS SD "
              "SL take a time: 'L 2s oBocina'). Examples: oAbrir, 'N oParado if Clock_1Hz', "
              "'P1 sCierres := sCierres + 1', 'on ↑iPieza do sN := sN + 1'.")
STEP_REFS = Def("stepRefs", one_of(Text(), ListOf(Text(), unique=True)),
                "A step name, or a list of step names (several: AND convergence in 'from', "
                "AND divergence in 'to'; [] in 'from': source transition, [] in 'to': sink "
                "transition).")
TRANSITION = Section((
    Key("from", STEP_REFS, "Upstream step(s).", required=True),
    Key("to", STEP_REFS, "Downstream step(s).", required=True),
    Key("when", one_of(Text(), Bool(), Int(0, 1)),
        "The condition (receptivity): an expression such as \"↑iMarcha·iParo'\" or 'RE "
        "iMarcha AND NOT iParo'; 1 or true for the always-true condition.", required=True),
    Key("name", Text(), "The transition's name (T1)."),
    Key("description", Text(), "Free text."),
), "a transition", "A transition. Their order in the file is their priority in an OR "
                   "divergence.")
#: a macro-step's expansion (its steps are ``innerStep``s: ``STEP`` with entry and exit)
MACRO = Section((
    Key("steps", MapOf(Ref("innerStep"), min_properties=1), "Steps of the expansion, by name.",
        required=True),
    Key("transitions", ListOf(Def("transition", TRANSITION)),
        "Transitions of the expansion."),
), doc="The macro-step's expansion: its own steps (exactly one with entry: true, one with "
       "exit: true) and transitions. Inner names share the chart's name space.")
_NO_ACTIONS_ON_A_MACRO = {"dependentSchemas": {"macro": {"not": {"required": ["actions"]}}},
                          "$comment": "dependentSchemas: a macro-step carries no actions of "
                                      "its own"}
#: a step, inside a macro-step's expansion or not (``entry`` and ``exit`` only inside)
STEP = Section((
    Key("initial", Bool(), "An initial step: active at start-up (and after "
                           "SFCInit/SFCReset)."),
    Key("actions", ACTIONS),
    Key("min", Time(), "Minimum time in the step: its outgoing transitions wait for it (e.g. "
                       "1s, T#500ms)."),
    Key("max", Time(), "Maximum time in the step: beyond it SFCError is set (supervision; the "
                       "step is not left)."),
    Key("macro", Def("macro", MACRO)),
    Key("entry", Bool(), "The entry step of the macro-step's expansion (exactly one)."),
    Key("exit", Bool(), "The exit step of the macro-step's expansion (exactly one)."),
    Key("description", DESCRIPTION, "Free text (shown by draw and the console)."),
    Key("renamed_from", Text(), "The step's former name, when an edit renames it: online "
                                "change then carries the running step (its activity and .T) "
                                "to the new name."),
), doc="A step of a macro-step's expansion. An empty step may be written {} or left empty.",
   null=True, extra=_NO_ACTIONS_ON_A_MACRO)
INNER_STEP = Def("innerStep", STEP)
GRAFCET = Section((
    Key("grafcet", Text(), "The chart's name (an identifier), like the name of a Siemens FB or "
                           "a CODESYS POU.", required=True),
    Key("description", Text(), "What the chart controls."),
    Key("scan", Choice(tuple(m.value for m in ScanModel)),
        "Evolution model: immediate (default: evolve, then act, in the same scan), codesys "
        "(CODESYS order: the situation decided by a scan becomes current in the next one), "
        "stable (IEC 60848 search for a stable situation).", default=ScanModel.IMMEDIATE.value),
    Key("inputs", ListOf(SIGNAL), "Inputs, positive logic (inversion happens at the binding). "
                                  "Bool unless typed: [iParo, {tTemperatura: int}]."),
    Key("outputs", ListOf(SIGNAL), "Outputs. Bool unless typed: [oAbrir, {oEstado: int}]."),
    Key("memory", MapOf(any_of(INITIAL, MEMORY_SPEC)),
        "Memory ('s') variables, keeping their value from scan to scan: name -> initial "
        "value, or {init, retain}."),
    Key("timers", ListOf(Text(), unique=True),
        "Seed-000 timer objects (timeX): timeX.Ini(t), timeX.End(), timeX.Reset(), "
        "timeX.Val()."),
    Key("blocks", MapOf(Doc(Choice(tuple(FB_MEMBERS)),
                            "TON TOF TP (IN PT -> Q ET), CTU (CU R PV -> Q CV), CTD (CD LD PV "
                            "-> Q CV), CTUD, R_TRIG F_TRIG (CLK -> Q), SR (S1 R -> Q1), RS (S "
                            "R1 -> Q1).")),
        "IEC 61131-3 function-block instances: name -> type."),
    Key("pre", STATEMENTS, "Previous calculations: run every scan before the transitions. "
                           "Undeclared assigned names are temporaries and must start with 't' "
                           "(tParo)."),
    Key("steps", MapOf(Def("step", STEP.without("entry", "exit", doc="A step. An empty step "
                                                "may be written {} or left empty.")),
                       min_properties=1),
        "The steps, by name (gsParado). At least one is initial.", required=True),
    Key("transitions", ListOf(Def("transition", TRANSITION)),
        "The transitions; order = priority in an OR divergence."),
    Key("post", STATEMENTS, "Posterior equations: run every scan after the actions (an output "
                            "assigned here overrides its action value)."),
), "a grafcet file", "One GRAFCET/SFC chart and its logic (softplc configuration language "
                     "v1, docs/language.md). It never names hardware: a plant file binds its "
                     "inputs and outputs.")


def _transition_shape(source: str) -> str:
    return f"- {{from: {source}, to: B, when: CONDITION}}"


def _locator(text: Any, fallback: Loc) -> Callable[[int], Loc]:
    if isinstance(text, YStr):
        return text.pos
    return lambda off: Loc(fallback.file, fallback.line, fallback.col + off)


def _identifier(name: str, loc: Loc, what: str) -> str:
    """A name as the lexer reads it: a letter or '_', then letters, digits and '_' (any
    alphabet: gsAvería); not a keyword of the expressions (AND, RE, TO ...)."""
    if not (isinstance(name, str) and is_name(name) and all(c.isalnum() or c == "_"
                                                            for c in name)):
        if str(name)[:1].isdigit():  # step 1 of a course's chart: a number is no name
            raise SourceError(loc, f"expected a name for {what} (a letter or '_' first, then "
                                   f"letters, digits, '_'), found the number '{name}': write "
                                   f"e.g. GS{name}")
        raise SourceError(loc, f"expected a name for {what} (letters, digits, '_'), found "
                               f"'{name}'")
    if name.upper() in KEYWORDS:
        raise SourceError(loc, f"expected a name for {what}, found the keyword '{name}'")
    return name


class GrafcetLoader:
    """Builds one Grafcet from a YAML mapping."""

    def __init__(self, path: str, doc: YMap, diagnostics: list[Diagnostic] | None = None
                 ) -> None:
        self.path = path
        self.doc = doc
        self.diagnostics = diagnostics
        self.g = Grafcet(name="", path=path, loc=doc.loc)
        self.units: list[tuple[str, str, Callable[[int], Loc], object]] = []
        self.stmt_index = 0
        self.transition_names: list[tuple[str, Loc]] = []  # each name given, where

    def _rule(self, code: str, loc: Loc, message: str) -> None:
        """A rule error the load can go on after: raised, or recorded if diagnostics are
        collected (the caller then leaves out what broke the rule)."""
        if self.diagnostics is None:
            raise SourceError(loc, message, code)
        self.diagnostics.append(Diagnostic(code, loc, message))

    def load(self) -> Grafcet:
        d, g = self.doc, self.g
        GRAFCET.check(d, misplaced=self._misplaced_at_top)
        if "grafcet" not in d:
            raise SourceError(d.loc, "missing key 'grafcet': expected the chart's name")
        g.name = _identifier(d["grafcet"], d.val_locs["grafcet"], "the grafcet")
        if "description" in d:
            g.description = free_text(d["description"], d.val_locs["description"],
                                      "a text for description")
        if "scan" in d:
            try:
                g.scan = ScanModel(d["scan"])
            except ValueError:
                raise SourceError(d.val_locs["scan"], f"unknown scan model '{d['scan']}': "
                                  "expected immediate, codesys or stable") from None
        self._signals("inputs", VarKind.INPUT)
        self._signals("outputs", VarKind.OUTPUT)
        self._memory()
        for name in FLAGS_BOOL:
            g.variables[name] = Variable(name, VarKind.FLAG, T.BOOL, name == "SFCEnableLimit",
                                         d.loc)
        for name in FLAGS_STRING:
            g.variables[name] = Variable(name, VarKind.FLAG, T.STRING, "", d.loc)
        for name in SYSTEM_BOOL:
            g.variables[name] = Variable(name, VarKind.SYSTEM, T.BOOL, False, d.loc)
        self._timers_blocks()
        if "steps" not in d:
            raise SourceError(d.loc, "missing key 'steps': a chart needs at least one step")
        steps = self._steps_mapping(d["steps"], d.val_locs["steps"])
        top = self._steps(steps, parent=None)
        transitions: list[Transition] = []
        if "transitions" in d:
            transitions += self._transitions(d["transitions"], d.val_locs["transitions"])
        for s in g.steps.values():
            if s.macro is not None:
                transitions += s.macro.transitions
        self._unique_transition_names()
        transitions.sort(key=lambda t: (t.loc.line, t.loc.col))
        for i, t in enumerate(transitions):
            t.index = i
        g.transitions = transitions
        if not any(g.steps[n].initial for n in g.steps):
            error = SourceError(d.key_locs["steps"], "the chart has no initial step: expected "
                                "a step with 'initial: true', found none among "
                                f"{', '.join(g.steps)}", "G101")
            if not g.steps:
                raise error  # nothing to go on with
            self._rule(error.code, error.loc, error.message)
            # go on as if the first step were initial (its expansion's entry step with it)
            first = g.steps[top[0]]
            first.initial = True
            if first.macro is not None:
                g.steps[first.macro.entry].initial = True
        del top
        self.pre_post()
        self._resolve_macros()
        self._typecheck_temps()
        return g

    def _misplaced_at_top(self, key: str) -> str | None:
        """Where a key of a step or of a transition written at the top level belongs."""
        steps = self.doc.get("steps")
        last = list(steps)[-1] if isinstance(steps, YMap) and steps else "NAME"
        if key in STEP:
            return (f": '{key}' is a key of a step: indent it under its step in 'steps:' "
                    f"(steps: {{{last}: {{{key}: [...]}}}})")
        if key in TRANSITION:
            return (f": '{key}' is a key of a transition: write it under 'transitions:' "
                    f"({_transition_shape('A')})")
        return None

    # -- declarations ------------------------------------------------------------
    def _declare(self, raw: Any, loc: Loc, what: str) -> str:
        name = _identifier(raw, loc, what)
        if name in self.g.variables or name in self.g.timers or name in self.g.blocks or (
                name in self.g.steps):
            raise SourceError(loc, f"'{name}' is declared twice")
        if name in FLAGS_BOOL + FLAGS_STRING + SYSTEM_BOOL:
            raise SourceError(loc, f"'{name}' is a built-in name")
        return name

    def _signals(self, key: str, kind: VarKind) -> None:
        d = self.doc
        if key not in d:
            return
        items = d[key]
        if items is None:
            return
        items = expect_type(items, d.val_locs[key], YList, f"a list of {key}")
        for item, loc in zip(items, items.locs, strict=True):
            typ = T.BOOL
            text = ""
            iec: tuple[Any, Loc] | None = None
            if isinstance(item, YMap):
                if len(item) != 1:
                    raise SourceError(loc, f"expected one '{{name: type}}' per typed signal, "
                                           f"found {len(item)} keys")
                (name, tname), = item.items()
                tloc = item.val_locs[name]
                if isinstance(tname, YMap):  # {name: {type: int, description: ...}}
                    SIGNAL_SPEC.check(tname, f"{key[:-1]} '{name}'")
                    if "description" in tname:
                        text = description_text(tname["description"],
                                                tname.val_locs["description"])
                    if "iec_type" in tname:
                        iec = tname["iec_type"], tname.val_locs["iec_type"]
                    tloc = tname.val_locs.get("type", tloc)
                    tname = tname.get("type", "bool")
                if not isinstance(tname, str) or tname not in TYPE_NAMES:
                    raise SourceError(tloc, f"unknown type '{tname}': expected bool, int, "
                                            "real or time")
                typ = TYPE_NAMES[tname]
                loc = item.key_locs[name]
            else:
                name = item
            name = self._declare(name, loc, f"an {key[:-1]}")
            self.g.variables[name] = Variable(name, kind, typ, _zero(typ), loc,
                                              description=text, iec_type=_iec_type(iec, typ))

    def _memory(self) -> None:
        d = self.doc
        if "memory" not in d or d["memory"] is None:
            return
        mem = expect_type(d["memory"], d.val_locs["memory"], YMap, "a mapping of memory")
        for name, spec in mem.items():
            loc = mem.key_locs[name]
            self._declare(name, loc, "a memory variable")
            retain = False
            was: str | None = None
            text = ""
            iec: tuple[Any, Loc] | None = None
            vloc = mem.val_locs[name]
            if isinstance(spec, YMap):
                MEMORY_SPEC.check(spec, f"memory '{name}'")
                if "description" in spec:
                    text = description_text(spec["description"], spec.val_locs["description"])
                retain = expect_type(spec.get("retain", False), spec.val_locs.get("retain", loc),
                                     bool, "true or false for retain")
                if "renamed_from" in spec:
                    was = _identifier(spec["renamed_from"], spec.val_locs["renamed_from"],
                                      "the former name (renamed_from)")
                if "iec_type" in spec:
                    iec = spec["iec_type"], spec.val_locs["iec_type"]
                vloc = spec.val_locs.get("init", vloc)
                spec = spec.get("init", False)
            typ, init = _initial(spec, vloc, name)
            self.g.variables[name] = Variable(name, VarKind.MEMORY, typ, init, loc, retain,
                                              renamed_from=was, description=text,
                                              iec_type=_iec_type(iec, typ))

    def _timers_blocks(self) -> None:
        d = self.doc
        if d.get("timers"):
            lst = expect_type(d["timers"], d.val_locs["timers"], YList, "a list of timer names")
            for name, loc in zip(lst, lst.locs, strict=True):
                self.g.timers[self._declare(name, loc, "a timer")] = loc
        if d.get("blocks"):
            blocks = expect_type(d["blocks"], d.val_locs["blocks"], YMap,
                                 "a mapping name: TON|TOF|TP|CTU|CTD|CTUD|R_TRIG|F_TRIG|SR|RS")
            for name, kind in blocks.items():
                loc = blocks.key_locs[name]
                self._declare(name, loc, "a function block")
                if not isinstance(kind, str) or kind not in FB_MEMBERS:
                    raise SourceError(blocks.val_locs[name], f"unknown function block type "
                                      f"'{kind}': expected one of {' '.join(FB_MEMBERS)}"
                                      f"{suggest(str(kind), FB_MEMBERS)}")
                self.g.blocks[name] = Block(name, kind, loc)

    # -- steps and transitions ------------------------------------------------------
    @staticmethod
    def _steps_mapping(value: Any, loc: Loc) -> YMap:
        """The mapping of steps; a list (steps written as '- NAME:' items) is refused with
        the shape expected."""
        if isinstance(value, YList):
            raise SourceError(loc, "expected the steps as a mapping, one step per line "
                                   "without '- ' (Ini: {initial: true} then Run: {actions: "
                                   "[oX]}), found a list")
        return expect_type(value, loc, YMap, "a mapping of steps")  # type: ignore[no-any-return]

    def _steps(self, steps: YMap, parent: str | None) -> list[str]:
        names: list[str] = []
        for name, spec in steps.items():
            loc = steps.key_locs[name]
            if name in STEP and spec is not None and not isinstance(spec, YMap):
                # a step's key (actions: [...]) indented at the level of the steps
                above = names[-1] if names else "NAME"
                raise SourceError(loc, f"expected a step, found '{name}', a key of a step, at "
                                       f"the level of the steps: indent it under its step, two "
                                       f"spaces further in than '{above}:' (or write {above}: "
                                       f"{{{name}: [...]}})")
            self._declare(name, loc, "a step")
            if spec is None:
                spec = YMap()
                spec.loc, spec.key_locs, spec.val_locs = loc, {}, {}
            if isinstance(spec, YList):
                raise SourceError(steps.val_locs[name], f"expected the definition of step "
                                  f"'{name}' (a mapping such as {{initial: true, actions: "
                                  "[oX]}), found a list: put the step's actions under "
                                  "'actions:'")
            spec = expect_type(spec, steps.val_locs[name], YMap, f"the definition of step "
                               f"'{name}' (a mapping such as {{initial: true, actions: [oX]}})")

            def in_step(key: str, name: str = name) -> str | None:
                if key in TRANSITION:
                    return (" (a transition is written under 'transitions:' as "
                            f"{_transition_shape(name)})")
                return None

            STEP.check(spec, f"step '{name}'", in_step)
            st = Step(name, loc, parent=parent)
            if "description" in spec:
                st.description = description_text(spec["description"],
                                                  spec.val_locs["description"])
            for flag in ("initial", "entry", "exit"):
                if flag in spec:
                    val = expect_type(spec[flag], spec.val_locs[flag], bool, "true or false")
                    setattr(st, flag, val)
            if (st.entry or st.exit) and parent is None:
                key = "entry" if st.entry else "exit"
                raise SourceError(spec.key_locs[key], f"'{key}' is for steps inside a macro-step "
                                  "expansion")
            if "renamed_from" in spec:
                st.renamed_from = _identifier(spec["renamed_from"], spec.val_locs["renamed_from"],
                                              "the former name (renamed_from)")
            for key in ("min", "max"):
                if key in spec:
                    setattr(st, f"{key}_ns", time_value(spec[key], spec.val_locs[key],
                                                        f"{key} of step '{name}'"))
            self.g.steps[name] = st
            names.append(name)
            if "macro" in spec:
                if "actions" in spec:
                    raise SourceError(spec.key_locs["actions"], f"macro-step '{name}' carries no "
                                      "actions of its own: put them on its inner steps")
                self._macro(st, spec["macro"], spec.val_locs["macro"])
            if "actions" in spec and spec["actions"] is not None:
                acts = spec["actions"]
                if isinstance(acts, str):
                    single = YList([acts])
                    single.loc = single_loc = spec.val_locs["actions"]
                    single.locs = [single_loc]
                    acts = single
                acts = expect_type(acts, spec.val_locs["actions"], YList, "a list of actions")
                for text, aloc in zip(acts, acts.locs, strict=True):
                    act = self._action(st, text, aloc)
                    if act is not None:
                        st.actions.append(act)
        return names

    def _macro(self, st: Step, spec: Any, loc: Loc) -> None:
        spec = expect_type(spec, loc, YMap, f"the expansion of macro-step '{st.name}'")
        MACRO.check(spec, f"macro-step '{st.name}'")
        if "steps" not in spec:
            raise SourceError(spec.loc, f"macro-step '{st.name}' needs 'steps'")
        inner = self._steps_mapping(spec["steps"], spec.val_locs["steps"])
        names = self._steps(inner, parent=st.name)
        entries = [n for n in names if self.g.steps[n].entry]
        exits = [n for n in names if self.g.steps[n].exit]
        if len(entries) != 1 or len(exits) != 1:
            which = "entry" if len(entries) != 1 else "exit"
            count = len(entries) if which == "entry" else len(exits)
            raise SourceError(spec.key_locs["steps"], f"macro-step '{st.name}' needs exactly one "
                              f"{which} step ('{which}: true'), found {count}")
        all_inner = []
        for n in names:
            all_inner.append(n)
            sub = self.g.steps[n].macro
            if sub is not None:
                all_inner += sub.steps
        trans = []
        if "transitions" in spec:
            trans = self._transitions(spec["transitions"], spec.val_locs["transitions"])
        st.macro = Macro(all_inner, trans, entries[0], exits[0])
        if st.initial:
            self.g.steps[entries[0]].initial = True

    def _transitions(self, items: Any, loc: Loc) -> list[Transition]:
        if isinstance(items, YMap):
            raise SourceError(loc, "expected a list of transitions, one per line after '- ' "
                                   "(- {from: Ini, to: Run, when: iMarcha}), found a mapping")
        items = expect_type(items, loc, YList, "a list of transitions")
        out = []
        for spec, tloc in zip(items, items.locs, strict=True):
            spec = expect_type(spec, tloc, YMap, "a transition {from, to, when}")
            TRANSITION.check(spec)
            for key in ("from", "to", "when"):
                if key not in spec:
                    raise SourceError(spec.loc, f"transition without '{key}'")
            srcs, src_locs = self._step_refs(spec["from"], spec.val_locs["from"], "from")
            dsts, dst_locs = self._step_refs(spec["to"], spec.val_locs["to"], "to")
            when = spec["when"]
            wloc = spec.val_locs["when"]
            written = isinstance(when, YStr)  # a text of the file, not a YAML bool or number
            if isinstance(when, bool):
                when = synthetic_str("TRUE" if when else "FALSE", wloc)
            elif isinstance(when, int):
                when = synthetic_str(str(when), wloc)
            when = expect_type(when, wloc, str, "a condition")
            locate = _locator(when, wloc)
            cond = parse_expression(when, locate)
            name = free_text(spec["name"], spec.val_locs["name"], "a name for the "
                             "transition") if "name" in spec else ""
            if "description" in spec:  # for a person reading the file: not kept
                free_text(spec["description"], spec.val_locs["description"],
                          "a text for description")
            t = Transition(srcs, dsts, cond, str(when), spec.loc, name=name, source_locs=src_locs,
                           target_locs=dst_locs, locate=locate if written else None)
            self.units.append(("bool", str(when), locate, cond))
            if t.name:
                self.transition_names.append((t.name, spec.val_locs["name"]))
            out.append(t)
        return out

    def _unique_transition_names(self) -> None:
        """Refuse a transition name given twice in the chart (macro expansions included),
        at the later one in the file."""
        first: dict[str, Loc] = {}
        for name, loc in sorted(self.transition_names, key=lambda n: (n[1].line, n[1].col)):
            if name in first:
                raise SourceError(loc, f"expected each transition name once in the chart, "
                                       f"found '{name}' again (first at line "
                                       f"{first[name].line})")
            first[name] = loc

    def _step_refs(self, value: Any, loc: Loc, key: str) -> tuple[list[str], list[Loc]]:
        if isinstance(value, str):
            return [str(value)], [loc]
        lst = expect_type(value, loc, YList, f"a step name or a list of steps in '{key}'")
        for v, vloc in zip(lst, lst.locs, strict=True):
            expect_type(v, vloc, str, "a step name")
        return [str(v) for v in lst], list(lst.locs)

    def _action(self, st: Step, text: Any, loc: Loc) -> Action | None:
        """The action, or None if it breaks a rule of seed 000 and diagnostics are
        collected (it is left out)."""
        text = expect_type(text, loc, str, "an action string")
        locate = _locator(text, loc)
        try:
            pa = parse_action(text, locate)
        except SourceError as exc:
            if not exc.code:
                raise
            self._rule(exc.code, exc.loc, exc.message)  # G105: 'on EVENT do oX'
            return None
        q = Qualifier(pa.qualifier)
        act = Action(q, st.name, str(text), loc, pa.time_ns, locate=locate)
        if pa.target is not None:
            if q in (Qualifier.P1, Qualifier.P0):
                self._rule("G105", locate(pa.target.start), f"expected statements after "
                           f"{q.value} (e.g. '{q.value} {pa.target.name} := 1'), found the "
                           f"bare variable '{pa.target.name}': a continuous action cannot be "
                           "tied to activation or deactivation (seed-000 rule I.6)")
                return None
            if pa.cond is not None and q is not Qualifier.N:
                raise SourceError(locate(pa.cond.start), f"expected 'if CONDITION' on an N "
                                  f"action only, found it with {q.value}")
            if pa.cond is not None:
                for n in A.walk(pa.cond):
                    if isinstance(n, A.Unary) and n.op in ("RE", "FE"):
                        self._rule("G106", locate(n.start), "expected a condition without "
                                   "edges in a conditional action (seed 000: the condition "
                                   f"has no event), found '{text[n.start:n.end]}': use 'on "
                                   "EVENT do'")
                        return None
            act.target = pa.target.name
            act.cond = pa.cond
            self._check_target(pa.target, locate)
            if pa.cond is not None:
                self.units.append(("bool", str(text), locate, pa.cond))
        else:
            if q in (Qualifier.S, Qualifier.R, Qualifier.DS, Qualifier.SD, Qualifier.SL):
                raise SourceError(locate(pa.qualifier_start), f"expected a bool variable "
                                  f"after {q.value} (e.g. '{q.value} oLamp'), found statements")
            if q is Qualifier.EVENT:
                act.event = pa.event
                self.units.append(("bool", str(text), locate, pa.event))
                ev = pa.event
                assert ev is not None
                if not any(isinstance(n, A.Unary) and n.op in ("RE", "FE") for n in A.walk(ev)):
                    raise SourceError(locate(ev.start), "expected an edge (↑x, ↓x, RE x, FE x) "
                                      "in the event of 'on EVENT do', found "
                                      f"'{text[ev.start:ev.end]}'")
            act.body = pa.body
            act.index = self.stmt_index
            self.stmt_index += 1
            self.units.append(("stmts", str(text), locate, pa.body))
        return act

    def _check_target(self, name: A.Name, locate: Callable[[int], Loc]) -> None:
        v = self.g.variables.get(name.name)
        if v is None:
            if looks_temporary(name.name):
                raise SourceError(locate(name.start), f"expected an output or memory variable "
                                  f"as the action's target, found '{name.name}' (a temporary "
                                  "cannot be driven by a step: declare it)")
            allv = [*self.g.variables, *self.g.steps]
            raise SourceError(locate(name.start), f"unknown variable '{name.name}'"
                              f"{suggest(name.name, allv)}")
        if v.kind not in (VarKind.OUTPUT, VarKind.MEMORY):
            raise SourceError(locate(name.start), f"expected an output or memory variable "
                              f"as the action's target, found {v.kind.value} '{name.name}'")
        if v.type is not T.BOOL:
            raise SourceError(locate(name.start), f"type error: expected a bool variable as the "
                              f"action's target, found {v.type} '{name.name}' (use a statement: "
                              f"'{name.name} := ...')")

    def pre_post(self) -> None:
        d = self.doc
        for key in ("pre", "post"):
            if key not in d or d[key] is None:
                continue
            items = d[key]
            if isinstance(items, str):
                lst = YList([items])
                lst.loc, lst.locs = d.val_locs[key], [d.val_locs[key]]
                items = lst
            items = expect_type(items, d.val_locs[key], YList, f"a list of {key} statements")
            out = getattr(self.g, key)
            for text, loc in zip(items, items.locs, strict=True):
                text = expect_type(text, loc, str, "a statement")
                locate = _locator(text, loc)
                body = parse_statements(text, locate)
                for s in body:
                    out.append(Statement(s, str(text)[s.start:s.end], locate(s.start), locate))
                self.units.append(("stmts", str(text), locate, body))

    def _resolve_macros(self) -> None:
        g = self.g

        def entry(name: str) -> str:
            st = g.steps[name]
            return entry(st.macro.entry) if st.macro else name

        def exit_(name: str) -> str:
            st = g.steps[name]
            return exit_(st.macro.exit) if st.macro else name

        for t in g.transitions:
            for key, names, where in (("from", t.sources, t.source_locs),
                                      ("to", t.targets, t.target_locs)):
                for i, n in enumerate(names):
                    if n not in g.steps:
                        loc = where[i] if i < len(where) else t.loc
                        raise SourceError(loc, f"unknown step '{n}' in the transition's "
                                               f"'{key}'{suggest(n, g.steps)}: expected a step "
                                               "of this chart")
            t.src_steps = [exit_(n) for n in t.sources]
            t.dst_steps = [entry(n) for n in t.targets]

    def _typecheck_temps(self) -> None:
        # every undeclared name assigned anywhere that looks like a temporary
        checker = Checker(self.g)
        for _, _src, locate, parsed in self.units:
            nodes = parsed if isinstance(parsed, list) else [parsed]
            for top in nodes:
                for n in A.walk(top):  # type: ignore[arg-type]
                    target = None
                    if isinstance(n, A.Assign):
                        target = n.target
                    elif isinstance(n, A.For):
                        target = n.var
                    elif isinstance(n, A.MethodCall) and n.method == "Set":
                        target = A.Name(n.start, n.start + len(n.obj), n.obj)
                    if target is None or target.name in self.g.variables:
                        continue
                    if target.name in self.g.steps or target.name in self.g.timers or (
                            target.name in self.g.blocks):
                        continue
                    if not looks_temporary(target.name):
                        allv = [*self.g.variables, *self.g.steps]
                        raise SourceError(locate(target.start), f"unknown variable "
                                          f"'{target.name}'{suggest(target.name, allv)}: "
                                          "expected a declared output or memory variable, or a "
                                          "temporary named 't' and a capital letter (tParo)")
                    checker.temps_pending.setdefault(target.name, locate(target.start))
        # temporaries are typed by their first assignment in file order
        self.units.sort(key=lambda u: (u[2](0).line, u[2](0).col))
        checker.run(self.units)


def _iec_type(iec: tuple[Any, Loc] | None, typ: A.Type) -> str:
    """A variable's ``iec_type`` ("" without one), checked against its type ``typ``: a
    refusal at its place names the types it may be."""
    if iec is None:
        return ""
    value, loc = iec
    allowed = IEC_TYPES.get(typ.value, ())
    value = expect_type(value, loc, str, "an IEC 61131-3 type for iec_type")
    if value not in allowed:
        raise SourceError(loc, f"iec_type {value} does not fit a variable of type {typ.value}: "
                               f"expected one of {', '.join(allowed)}")
    return "" if value == allowed[0] else str(value)


def _zero(t: A.Type) -> object:
    return {T.BOOL: False, T.INT: 0, T.REAL: 0.0, T.TIME: 0, T.STRING: ""}[t]


def _initial(spec: Any, loc: Loc, name: str) -> tuple[A.Type, object]:
    if isinstance(spec, bool):
        return T.BOOL, spec
    if isinstance(spec, int):
        return T.INT, spec
    if isinstance(spec, float):
        return T.REAL, spec
    expected = (f"expected an initial value for '{name}': false or true (bool), an integer "
                "such as 0 (int), a real such as 0.0 (real) or a time such as 10s (time)")
    if isinstance(spec, str):
        text = spec.strip()
        if text.upper() in ("TRUE", "FALSE"):
            return T.BOOL, text.upper() == "TRUE"
        if text[:1].isdigit() or text.upper().startswith(("T#", "TIME#")):
            return T.TIME, time_value(text, loc, f"the initial value of '{name}'")
        raise SourceError(loc, f"{expected}, found the text '{text}'{yaml11_bool_note(text)}")
    found = "nothing" if spec is None else "a mapping" if isinstance(spec, YMap) else (
        "a list" if isinstance(spec, YList) else repr(spec))
    raise SourceError(loc, f"{expected}, found {found}")


def load_grafcet(path: str, diagnostics: list[Diagnostic] | None = None, *,
                 doc: Any = None) -> Grafcet:
    """Load and type-check one grafcet file; each call reads the file anew, unless ``doc``
    gives its document as ``load_yaml(path)`` returned it (a caller that already read it).

    With ``diagnostics``, the rule errors the load can go on after are appended to it
    instead of raised (see the module's docstring); any other error is raised."""
    if doc is None:
        doc = load_yaml(path)
    if not isinstance(doc, YMap):
        raise SourceError(Loc(path, 1, 1), "expected a YAML mapping with 'grafcet:' and 'steps:'")
    return GrafcetLoader(path, doc, diagnostics).load()
