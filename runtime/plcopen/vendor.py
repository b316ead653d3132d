"""CODESYS's vendor data: the ``attribute`` elements, keyed by a GUID, that CODESYS writes
into the ``addData`` of its SFC elements (step names, initial flag, min/max times, step
actions, transition priorities)."""

from __future__ import annotations

from runtime.plcopen.schema import CODESYS_GUIDS, CODESYS_SFC_DATA, PLCOPEN_NS
from runtime.plcopen.xmltree import Element


def codesys_attributes(e: Element) -> dict[str, str]:
    """Meaning (``CODESYS_GUIDS``'s words) -> text of CODESYS's SFC attributes of ``e``."""
    out: dict[str, str] = {}
    add = e.find("addData", PLCOPEN_NS)
    if add is None:
        return out
    for data in add.findall("data", PLCOPEN_NS):
        if data.get("name") != CODESYS_SFC_DATA:
            continue
        for attrs in data.children:
            for a in attrs.children:
                guid = (a.get("guid") or "").strip("{}").lower()
                meaning = CODESYS_GUIDS.get(guid)
                if meaning is not None:
                    out[meaning] = a.text.strip()
    return out


def codesys_objects(pou: Element, kind: str) -> list[Element]:
    """The POU's actions (``kind`` "action") or transitions ("transition") that CODESYS
    keeps in the POU's vendor data (``data name=".../plcopenxml/action"``) instead of the
    schema's ``actions``/``transitions``."""
    add = pou.find("addData", PLCOPEN_NS)
    if add is None:
        return []
    out = []
    for data in add.findall("data", PLCOPEN_NS):
        if data.get("name") == f"http://www.3s-software.com/plcopenxml/{kind}":
            out += data.findall(kind, PLCOPEN_NS)
    return out


def is_codesys(root: Element) -> bool:
    """Whether a project comes from CODESYS (or a tool built on it): its header names 3S or
    CODESYS, or it holds CODESYS's vendor data."""
    head = root.find("fileHeader", PLCOPEN_NS)
    if head is not None:
        who = f"{head.get('companyName', '')} {head.get('productName', '')}".lower()
        if "codesys" in who or "3s-smart" in who or "3s smart" in who:
            return True
    return any(e.tag == "data" and (e.get("name") or "").startswith(
        "http://www.3s-software.com/") for e in root.iter())
