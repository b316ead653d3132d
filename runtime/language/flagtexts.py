"""What the chart flags and a driver's health mean to a person: the one text of each, which
every display reads through the plant's I/O list (``IOList.meaning``, runtime/language/
iolist.py): the OPC UA Description, the MQTT metrics' ``description`` property, the
console's ``get`` and the web page. tests/engine/test_flag_texts.py holds each text to what
the engine does (a chart with two active steps, a step over its max time, tip mode...):
a text that no longer says what the flag does fails there. docs/language.md ("Built-in
variables and chart flags") and docs/semantics.md ("Chart flags") say the same at length.
``sfcerror_cause`` words who set an SFCError, for every display that says it.
"""

from __future__ import annotations

#: chart flag -> what it means (the language's own, not the plant's)
FLAG_TEXT = {
    "SFCInit": "while true: the chart is held in its initial situation",
    "SFCReset": "while true: the chart is reset to its initial situation",
    "SFCPause": "while true: the chart is paused (no transition fires)",
    "SFCError": "set by a step over its max time, until acknowledged",
    "SFCErrorStep": "the step that set SFCError",
    "SFCEnableLimit": "max time supervision on (default true)",
    "SFCQuitError": "while true: SFCError cleared and the chart paused",
    "SFCTipMode": "while true: the chart steps only on SFCTip",
    "SFCTip": "in tip mode: one step per rising edge",
    "SFCCurrentStep": "the last active step in file order (empty when none is active)",
}
#: what a driver's ``ok`` point means
HEALTH_TEXT = "true while the driver is healthy"


def sfcerror_cause(step: str, about: str = "") -> str:
    """Who set an instance's SFCError, as every display says it (the log, the alarms, the
    console and the monitor, the OPC UA events): ``set by step NAME`` (``about``, the step's
    description, in brackets) when a step over its max time set it, ``set by the chart``
    when SFCErrorStep is empty (the chart, or a write to the flag, set it)."""
    if not step:
        return "set by the chart"
    return f"set by step {step}" + (f" ({about})" if about else "")
