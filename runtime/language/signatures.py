"""The signatures of the function blocks and seed timers a chart may use: declared once,
for the type checker, the chart loader, the trace and the compiler's implementations
(``runtime/compiler/blocks.py``, checked against these by a test)."""

from __future__ import annotations

from runtime.language import ast as A

T = A.Type

#: function block kind -> member -> (type, is_input); times in ns
FB_MEMBERS: dict[str, dict[str, tuple[A.Type, bool]]] = {
    "TON": {"IN": (T.BOOL, True), "PT": (T.TIME, True), "Q": (T.BOOL, False),
            "ET": (T.TIME, False)},
    "CTU": {"CU": (T.BOOL, True), "R": (T.BOOL, True), "PV": (T.INT, True),
            "Q": (T.BOOL, False), "CV": (T.INT, False)},
    "CTD": {"CD": (T.BOOL, True), "LD": (T.BOOL, True), "PV": (T.INT, True),
            "Q": (T.BOOL, False), "CV": (T.INT, False)},
    "CTUD": {"CU": (T.BOOL, True), "CD": (T.BOOL, True), "R": (T.BOOL, True),
             "LD": (T.BOOL, True), "PV": (T.INT, True), "QU": (T.BOOL, False),
             "QD": (T.BOOL, False), "CV": (T.INT, False)},
    "R_TRIG": {"CLK": (T.BOOL, True), "Q": (T.BOOL, False)},
    "SR": {"S1": (T.BOOL, True), "R": (T.BOOL, True), "Q1": (T.BOOL, False)},
    "RS": {"S": (T.BOOL, True), "R1": (T.BOOL, True), "Q1": (T.BOOL, False)},
}
FB_MEMBERS["TOF"] = FB_MEMBERS["TP"] = FB_MEMBERS["TON"]
FB_MEMBERS["F_TRIG"] = FB_MEMBERS["R_TRIG"]

#: seed-timer method -> (number of arguments, result type, is a statement)
TIMER_METHODS: dict[str, tuple[int, A.Type, bool]] = {
    "Ini": (1, T.TIME, True), "End": (0, T.BOOL, False), "Reset": (0, T.TIME, True),
    "Val": (0, T.TIME, False)}
