"""The check every generated program passes before it runs: its text and its compiled code
hold only what the compiler emits.

The compiler writes Python as text (docs/architecture.md, "Generated code"): names it made,
literals made by ``repr`` and comments made single-line by
:func:`runtime.compiler.emit.comment`. Nothing of a chart, plant or imported file is meant
to reach the text otherwise; this module is the defence in depth for the day an emitter
gets that wrong. Every generated program (the scan of a chart, the plant's cycle and its
inlined groups, the small lambdas of ``explain`` and the step times; in ``compile``,
``simulate``, ``run``, the reload's child and the controller it hands its code to) goes
through :func:`checked_code`:

- its text: every line printable (no CR, VT, FF, NUL, NEL, U+2028 ... inside a line), so
  the compiler, ``tokenize`` and the inliner's ``split("\\n")`` see the same lines;
- its code, as compiled, every function and lambda in it: only the operations the
  compiler's constructs compile to (:data:`OPERATIONS`: no import, class, global store,
  ``with``, f-string, keyword or star call, loop over an iterable ...); every global or
  attribute name one the program defines, one its caller hands it, one of
  :data:`BUILTINS` or one of :data:`ATTRIBUTES` (the function blocks' members and methods,
  a driver's ``health``); no dunder name anywhere; constants numbers, booleans, None and
  strings.

The code checked is the code that runs, whoever compiled it: a code object the reload's
child compiled (``CodeBook``) is checked here again. Why the code and not the syntax tree:
the same vocabulary checked on the tree (``ast.parse``, a walk, ``compile`` of the tree)
made a 1000-step chart's compilation four times as long (1.58 s of processor time against
0.38 s); checked on the code it costs 5 ms. The operations are CPython's own and change
between versions: :data:`OPERATIONS` lists those of 3.11, 3.12 and 3.13 (each checked on
every generated program of the test suite); another version's compiler that emits an
operation outside the list is refused, never let through. A program that fails is refused
with one line (:class:`GeneratedCodeRefused`): a defect of the compiler, nothing of it ran.
"""

from __future__ import annotations

import builtins
import dis
from collections.abc import Collection
from types import CodeType
from typing import Any

from runtime.errors import SoftplcError
from runtime.language.signatures import FB_MEMBERS, TIMER_METHODS

#: the builtins a generated program may name (integer conversion of a REAL division, a FOR
#: loop's error, the generator protocol of the inlined groups)
BUILTINS: frozenset[str] = frozenset(
    {"int", "float", "ZeroDivisionError", "BaseException", "GeneratorExit"})

#: the attributes a generated program may read, write or call: the function blocks'
#: members and their ``update``, the seed timers' methods (lower case, as
#: compiler/blocks.py names them), a driver's ``health``, the list methods of the inlined
#: groups' fault box
ATTRIBUTES: frozenset[str] = frozenset(
    {m for members in FB_MEMBERS.values() for m in members}
    | {m.lower() for m in TIMER_METHODS}
    | {"update", "health", "append", "pop"})

#: the operations the compiler's constructs compile to on CPython 3.11, 3.12 and 3.13:
#: locals, cells, globals and attributes (checked by name), constants, operators,
#: comparisons, branches and ``while`` loops, calls with positional arguments, tuples and
#: lists, functions and closures, ``try``/``except``/``raise``, generators' ``yield``
OPERATIONS: frozenset[str] = frozenset({
    "CACHE", "NOP", "RESUME", "EXTENDED_ARG", "POP_TOP", "PUSH_NULL", "COPY", "SWAP",
    "LOAD_CONST", "LOAD_FAST", "LOAD_FAST_CHECK", "LOAD_FAST_LOAD_FAST", "STORE_FAST",
    "STORE_FAST_STORE_FAST", "DELETE_FAST", "LOAD_DEREF", "STORE_DEREF", "LOAD_CLOSURE",
    "MAKE_CELL", "COPY_FREE_VARS", "LOAD_GLOBAL", "LOAD_NAME", "STORE_NAME", "LOAD_ATTR",
    "LOAD_METHOD", "STORE_ATTR", "BINARY_SUBSCR", "STORE_SUBSCR",
    "BINARY_OP", "UNARY_NOT", "UNARY_NEGATIVE", "TO_BOOL", "COMPARE_OP", "IS_OP",
    "CONTAINS_OP",
    "JUMP_FORWARD", "JUMP_BACKWARD", "JUMP_BACKWARD_NO_INTERRUPT", "JUMP_IF_FALSE_OR_POP",
    "JUMP_IF_TRUE_OR_POP", "POP_JUMP_IF_FALSE", "POP_JUMP_IF_TRUE", "POP_JUMP_IF_NONE",
    "POP_JUMP_FORWARD_IF_FALSE", "POP_JUMP_FORWARD_IF_TRUE", "POP_JUMP_FORWARD_IF_NONE",
    "POP_JUMP_BACKWARD_IF_FALSE", "POP_JUMP_BACKWARD_IF_TRUE",
    "PRECALL", "CALL", "BUILD_TUPLE", "BUILD_LIST", "LIST_APPEND", "LIST_EXTEND",
    "LIST_TO_TUPLE",
    "UNPACK_SEQUENCE", "MAKE_FUNCTION", "SET_FUNCTION_ATTRIBUTE", "RETURN_VALUE",
    "RETURN_CONST", "RETURN_GENERATOR", "YIELD_VALUE", "PUSH_EXC_INFO", "POP_EXCEPT",
    "CHECK_EXC_MATCH", "RERAISE", "RAISE_VARARGS", "CALL_INTRINSIC_1",
})
_OPCODES = frozenset(dis.opmap[n] for n in OPERATIONS if n in dis.opmap) | {0}  # 0: CACHE
#: ``CALL_INTRINSIC_1`` (3.12+) with an argument other than these is refused: 3 turns a
#: generator's StopIteration into RuntimeError (every generator has it), 5 is unary ``+``,
#: 6 a long tuple built as a list (3.11's LIST_TO_TUPLE)
_INTRINSICS = frozenset({3, 5, 6})
_INTRINSIC = dis.opmap.get("CALL_INTRINSIC_1")
#: the types a constant may have (tuples and frozensets of them: folded constants)
_CONSTANTS = (bool, int, float, str, type(None))


class GeneratedCodeRefused(SoftplcError):
    """A generated program holds something the compiler does not emit: a line break inside
    a line, an import, a name it neither defines nor was given, a dunder, an attribute
    outside :data:`ATTRIBUTES` ... Nothing of it ran (a compiler defect: the chart, plant
    or imported file that led to it is kept as it is)."""

    def __init__(self, filename: str, line: int, what: str) -> None:
        super().__init__(f"generated code of {filename} refused at its line {line}: {what} "
                         "(a defect of softplc's compiler: nothing of it ran)")
        self.filename = filename
        self.line = line
        self.what = what


def _printable_lines(source: str, filename: str) -> None:
    """Refuse a source with a character that ends or breaks a line anywhere but ``\\n``."""
    if source.replace("\n", "").isprintable():
        return  # the usual case, in two C calls
    for number, line in enumerate(source.split("\n"), 1):
        if not line.isprintable():
            bad = next(c for c in line if not c.isprintable())
            raise GeneratedCodeRefused(filename, number, f"the character {bad!r} in a line")


def _codes(code: CodeType) -> list[CodeType]:
    """``code`` and every code object nested in it (functions, lambdas)."""
    out, todo = [], [code]
    while todo:
        c = todo.pop()
        out.append(c)
        todo += [k for k in c.co_consts if isinstance(k, CodeType)]
    return out


def _line_of(code: CodeType, test: Any) -> int:
    """The source line of the first instruction of ``code`` for which ``test`` holds (the
    refusal's place: computed only when refusing)."""
    line = code.co_firstlineno
    for ins in dis.get_instructions(code):
        if ins.positions is not None and ins.positions.lineno is not None:
            line = ins.positions.lineno
        if test(ins):
            return line
    return code.co_firstlineno


def _constant_ok(value: object) -> bool:
    if isinstance(value, tuple | frozenset):
        return all(_constant_ok(v) for v in value)
    return isinstance(value, CodeType) or type(value) in _CONSTANTS


def check_code(code: CodeType, filename: str, names: Collection[str],
               attributes: Collection[str] = ()) -> None:
    """Refuse ``code`` unless it holds only what the compiler emits (module docstring);
    ``names``: the globals the program is given; ``attributes``: more attributes it may
    use (beyond :data:`ATTRIBUTES`)."""
    codes = _codes(code)
    defined = {c.co_name for c in codes}
    allowed = BUILTINS | ATTRIBUTES | defined | set(names) | set(attributes)
    for c in codes:
        ops = set(c.co_code[::2])
        if not ops <= _OPCODES:
            bad = min(ops - _OPCODES)
            raise GeneratedCodeRefused(filename, _line_of(c, lambda i, b=bad: i.opcode == b),
                                       f"the operation {dis.opname[bad]}")
        if _INTRINSIC in ops:
            raw, at = c.co_code, c.co_code.find(_INTRINSIC)
            while at >= 0:
                if at % 2 == 0 and raw[at + 1] not in _INTRINSICS:
                    raise GeneratedCodeRefused(filename, _line_of(
                        c, lambda i: i.opcode == _INTRINSIC and i.arg not in _INTRINSICS),
                        f"the intrinsic call {raw[at + 1]}")
                at = raw.find(_INTRINSIC, at + 1)
        for name in c.co_names:
            if name not in allowed or name.startswith("__"):
                raise GeneratedCodeRefused(filename, _line_of(
                    c, lambda i, n=name: i.argval == n), f"the name {name!r}")
        for name in (*c.co_varnames, *c.co_cellvars, *c.co_freevars):
            if name.startswith("__"):
                raise GeneratedCodeRefused(filename, c.co_firstlineno, f"the name {name!r}")
        for value in c.co_consts:
            if not _constant_ok(value):
                raise GeneratedCodeRefused(filename, _line_of(
                    c, lambda i, v=value: i.opname == "LOAD_CONST" and i.argval is v),
                    f"a constant of type {type(value).__name__}")


def checked_code(source: str, filename: str, names: Collection[str], mode: str = "exec",
                 attributes: Collection[str] = ()) -> CodeType:
    """``compile(source, filename, mode)``, refused unless its text and its code pass the
    checks (module docstring); ``names``: the globals the program is given,
    ``attributes``: more attributes it may use."""
    _printable_lines(source, filename)
    try:
        code = compile(source, filename, mode)
    except SyntaxError as e:
        raise GeneratedCodeRefused(filename, e.lineno or 0, f"a syntax error ({e.msg})") \
            from None
    check_code(code, filename, names, attributes)
    return code


def restricted_builtins() -> dict[str, object]:
    """The ``__builtins__`` of a generated program's globals: :data:`BUILTINS` alone."""
    return {name: getattr(builtins, name) for name in BUILTINS}


def checked_eval(source: str, env: dict[str, Any], attributes: Collection[str] = ()) -> Any:
    """``eval`` of a generated expression (a lambda) once checked as :func:`checked_code`;
    ``env``: its globals, the only names it is given (its ``__builtins__`` made
    :func:`restricted_builtins`); ``attributes``: more attributes it may use."""
    code = checked_code(source, "<generated expression>", env.keys(), "eval", attributes)
    return eval(code, {**env, "__builtins__": restricted_builtins()})  # noqa: S307


__all__ = ["ATTRIBUTES", "BUILTINS", "OPERATIONS", "GeneratedCodeRefused", "check_code",
           "checked_code", "checked_eval", "restricted_builtins"]
