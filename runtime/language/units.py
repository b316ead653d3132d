"""Units of measure of the I/O list (``unit:`` of a binding): UN/CEFACT Recommendation 20
codes, as OPC UA's EngineeringUnits carries them (Part 8, 5.6.3).

A unit is written as its code (``CEL``), its symbol (``°C``) or one of a few ASCII
spellings (``degC``); :data:`UNITS` is the table known here, the units of automation
(temperatures, pressures, lengths, flows, masses, forces, power and energy, electrical
quantities, speeds, times, ratios). Codes, symbols and names as the OPC Foundation's
UNECE-to-OPC UA table gives them.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

#: EngineeringUnits' namespace for UN/CEFACT codes (OPC UA Part 8, 5.6.3)
CEFACT_URI = "http://www.opcfoundation.org/UA/units/un/cefact"


@dataclass(frozen=True, slots=True)
class Unit:
    """A unit of measure: its UN/CEFACT code, symbol and English name."""

    code: str
    symbol: str
    name: str

    @property
    def unit_id(self) -> int:
        """OPC UA's UnitId of the code: its characters as bytes of one integer."""
        n = 0
        for ch in self.code:
            n = (n << 8) | ord(ch)
        return n


_TABLE = (
    # temperature
    ("CEL", "°C", "degree Celsius"), ("FAH", "°F", "degree Fahrenheit"),
    ("KEL", "K", "kelvin"),
    # pressure
    ("BAR", "bar", "bar"), ("MBR", "mbar", "millibar"), ("PAL", "Pa", "pascal"),
    ("A97", "hPa", "hectopascal"), ("KPA", "kPa", "kilopascal"),
    ("MPA", "MPa", "megapascal"), ("PS", "lbf/in²", "pound-force per square inch"),
    # length, area, volume
    ("4H", "µm", "micrometre"), ("MMT", "mm", "millimetre"), ("CMT", "cm", "centimetre"),
    ("MTR", "m", "metre"), ("KMT", "km", "kilometre"), ("MTK", "m²", "square metre"),
    ("MLT", "ml", "millilitre"), ("LTR", "l", "litre"), ("MTQ", "m³", "cubic metre"),
    # speed, acceleration, rotation, angle
    ("C16", "mm/s", "millimetre per second"), ("MTS", "m/s", "metre per second"),
    ("KMH", "km/h", "kilometre per hour"), ("MSK", "m/s²", "metre per second squared"),
    ("RPM", "r/min", "revolutions per minute"), ("2A", "rad/s", "radian per second"),
    ("DD", "°", "degree (angle)"), ("C81", "rad", "radian"),
    # flow
    ("L2", "l/min", "litre per minute"), ("MQH", "m³/h", "cubic metre per hour"),
    ("MQS", "m³/s", "cubic metre per second"), ("E93", "kg/h", "kilogram per hour"),
    # mass, force, torque
    ("GRM", "g", "gram"), ("KGM", "kg", "kilogram"), ("TNE", "t", "tonne"),
    ("NEW", "N", "newton"), ("B47", "kN", "kilonewton"), ("NU", "N·m", "newton metre"),
    # power, energy
    ("WTT", "W", "watt"), ("KWT", "kW", "kilowatt"), ("MAW", "MW", "megawatt"),
    ("WHR", "W·h", "watt hour"), ("KWH", "kW·h", "kilowatt hour"),
    ("MWH", "MW·h", "megawatt hour"), ("JOU", "J", "joule"), ("KJO", "kJ", "kilojoule"),
    ("D46", "V·A", "volt-ampere"), ("KVA", "kV·A", "kilovolt-ampere"),
    ("KVR", "kvar", "kilovar"),
    # electrical
    ("2Z", "mV", "millivolt"), ("VLT", "V", "volt"), ("KVT", "kV", "kilovolt"),
    ("4K", "mA", "milliampere"), ("AMP", "A", "ampere"), ("B22", "kA", "kiloampere"),
    ("OHM", "Ω", "ohm"), ("HTZ", "Hz", "hertz"), ("KHZ", "kHz", "kilohertz"),
    # time
    ("C26", "ms", "millisecond"), ("SEC", "s", "second"), ("MIN", "min", "minute"),
    ("HUR", "h", "hour"), ("DAY", "d", "day"),
    # ratios, counts, light, sound
    ("P1", "%", "percent"), ("59", "ppm", "part per million"), ("C62", "1", "one"),
    ("LUX", "lx", "lux"), ("2N", "dB", "decibel"),
)
#: every unit known here, by code
UNITS: dict[str, Unit] = {code: Unit(code, sym, name) for code, sym, name in _TABLE}
#: symbols and ASCII spellings -> code
_SPELLINGS: dict[str, str] = {u.symbol: u.code for u in UNITS.values()}
_SPELLINGS.update({"L": "LTR", "degC": "CEL", "degF": "FAH", "deg": "DD", "um": "4H",
                   "m2": "MTK", "m3": "MTQ", "m3/h": "MQH", "m3/s": "MQS", "m/s2": "MSK",
                   "rpm": "RPM", "Nm": "NU", "Wh": "WHR", "kWh": "KWH", "MWh": "MWH",
                   "VA": "D46", "kVA": "KVA", "ohm": "OHM", "psi": "PS", "pct": "P1"})
#: the unit of every TIME value shown in a number (OPC UA's Duration, the console's ms)
MILLISECOND = UNITS["C26"]
#: what each unit measures, by code: how a suggestion tells a length from a time
QUANTITY: dict[str, str] = {
    **dict.fromkeys(("CEL", "FAH", "KEL"), "temperature"),
    **dict.fromkeys(("BAR", "MBR", "PAL", "A97", "KPA", "MPA", "PS"), "pressure"),
    **dict.fromkeys(("4H", "MMT", "CMT", "MTR", "KMT"), "length"),
    "MTK": "area", **dict.fromkeys(("MLT", "LTR", "MTQ"), "volume"),
    **dict.fromkeys(("C16", "MTS", "KMH"), "speed"), "MSK": "acceleration",
    **dict.fromkeys(("RPM", "2A"), "rotational speed"), **dict.fromkeys(("DD", "C81"), "angle"),
    **dict.fromkeys(("L2", "MQH", "MQS", "E93"), "flow"),
    **dict.fromkeys(("GRM", "KGM", "TNE"), "mass"), **dict.fromkeys(("NEW", "B47"), "force"),
    "NU": "torque", **dict.fromkeys(("WTT", "KWT", "MAW"), "power"),
    **dict.fromkeys(("WHR", "KWH", "MWH", "JOU", "KJO"), "energy"),
    **dict.fromkeys(("D46", "KVA"), "apparent power"), "KVR": "reactive power",
    **dict.fromkeys(("2Z", "VLT", "KVT"), "voltage"),
    **dict.fromkeys(("4K", "AMP", "B22"), "current"), "OHM": "resistance",
    **dict.fromkeys(("HTZ", "KHZ"), "frequency"),
    **dict.fromkeys(("C26", "SEC", "MIN", "HUR", "DAY"), "time"),
    **dict.fromkeys(("P1", "59", "C62"), "ratio"), "LUX": "illuminance", "2N": "sound level",
}
#: at most this many units suggested for an unknown one
SUGGESTED = 3


def find_unit(text: str) -> Unit | None:
    """The unit written ``text`` (a code, a symbol or an ASCII spelling), or None."""
    code = text if text in UNITS else _SPELLINGS.get(text)
    return UNITS[code] if code is not None else None


def spellings() -> list[str]:
    """Every way a unit may be written (for suggestions)."""
    return [*UNITS, *_SPELLINGS]


def suggest_unit(text: str) -> str:
    """`` (did you mean 'cm' (centimetre, a length) or 'ms' (millisecond, a time)?)`` for an
    unknown unit ``text``, or "". Each candidate names what it measures, so that the writer
    picks by the kind of the signal (a level is a length, not a time): the loader does not
    know what a signal measures, only that it is a number. First the spelling that differs
    only by letter case or a plural ``s`` (``cms``, ``degc``), then the closest spellings,
    one per unit."""
    ways = spellings()
    first = sorted((w for w in ways
                    if w.lower() in (text.lower(), text.lower().removesuffix("s"))),
                   key=lambda w: (w not in (text, text.removesuffix("s")), w in UNITS))
    close = difflib.get_close_matches(text, ways, n=8, cutoff=0.6)
    chosen: dict[str, str] = {}  # code -> the spelling shown
    for w in [*first, *close]:
        unit = find_unit(w)
        if unit is not None and unit.code not in chosen and len(chosen) < SUGGESTED:
            chosen[unit.code] = w
    if not chosen:
        return ""
    said = [f"'{w}' ({UNITS[code].name}, {_a(QUANTITY[code])})" for code, w in chosen.items()]
    return f" (did you mean {' or '.join(said)}?)"


def _a(noun: str) -> str:
    return f"{'an' if noun[0] in 'aeiou' else 'a'} {noun}"
