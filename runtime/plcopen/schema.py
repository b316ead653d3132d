"""The names of PLCopen TC6 XML v2.01 that the importer and the exporter share: namespaces,
qualifiers, softplc's own additional data, CODESYS's vendor data."""

from __future__ import annotations

from runtime.language.model import IEC_TYPES

#: PLCopen TC6 XML v2.01 (IEC 61131-10)
PLCOPEN_NS = "http://www.plcopen.org/xml/tc6_0201"
#: the text of ST bodies and documentation (``formattedText``)
XHTML_NS = "http://www.w3.org/1999/xhtml"
#: softplc's additional data: the ``name`` of its ``addData/data`` elements and the
#: namespace of what they hold (docs/plcopen.md, "softplc's additional data")
SOFTPLC_NS = "urn:softplc:plcopen:1"
#: the prefix softplc writes for SOFTPLC_NS
SOFTPLC_PREFIX = "sp"
#: CODESYS's vendor data of SFC elements: ``attribute`` elements keyed by a GUID
CODESYS_SFC_DATA = "http://www.3s-software.com/plcopenxml/sfc/element"

#: the CODESYS SFC attributes softplc reads, GUID -> meaning
CODESYS_GUIDS = {
    "38391c6d-6d4a-42f8-8ee7-9f45e5adafa8": "name",
    "7d894980-aeea-405c-a0f6-e2b26429c58f": "comment",
    "6844a48e-46c2-4cc8-a185-a478f3b99cc0": "initial",
    "cacf1a68-236e-47c2-b7b1-1cf9199718cb": "min",
    "b693554c-1b01-4a8d-afde-9e3a46f7465d": "max",
    "700a583f-b4d4-43e4-8c14-629c7cd3bec8": "main",
    "a6b08bd8-b696-47e3-9cbf-7408b61c9ff8": "entry",
    "a2621e18-7de3-4ea6-ae6d-89e9e0b7befd": "exit",
    "8294df19-5962-4dee-a874-1051dabb0e3e": "priority",
}

#: the qualifiers of ``actionBlock/action`` in the schema (N is the default)
QUALIFIERS = ("N", "R", "S", "L", "D", "P", "P1", "P0", "DS", "DL", "SD", "SL")
#: qualifiers that take a ``duration``
TIMED = frozenset({"L", "D", "SD", "DS", "SL", "DL"})

#: IEC 61131-3 elementary types -> the language's types (runtime/language/model.py)
INT_TYPES = frozenset(IEC_TYPES["int"])
REAL_TYPES = frozenset(IEC_TYPES["real"])
#: the language's types -> what an export declares for a variable without ``iec_type``
EXPORT_TYPES = {t: names[0] for t, names in IEC_TYPES.items()}
