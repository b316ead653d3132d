"""The global variables of a PLCopen file's configurations and resources, and which of them
a POU's ``VAR_EXTERNAL`` reaches.

IEC 61131-3 scopes a global to its configuration or resource: a POU run by a resource's
task (directly, or as a function block instance of a program that task runs) sees that
resource's globals and its configuration's, the resource's first (a resource's global of a
name hides its configuration's). A POU that no task runs sees every configuration's
globals and every resource's, the first declared of each name.
"""

from __future__ import annotations

from dataclasses import dataclass

from runtime.plcopen.schema import PLCOPEN_NS
from runtime.plcopen.xmltree import Element


@dataclass(frozen=True)
class Global:
    """One variable of a ``globalVars`` list."""

    e: Element  # the ``variable``
    owner: str  # "configuration 'config'" or "resource 'resource1'"
    constant: bool
    retained: bool


def _globals_of(holder: Element, owner: str) -> dict[str, Global]:
    out: dict[str, Global] = {}
    for lst in holder.findall("globalVars", PLCOPEN_NS):
        constant = lst.get("constant") == "true"
        retained = lst.get("retain") == "true" or lst.get("persistent") == "true"
        for v in lst.findall("variable", PLCOPEN_NS):
            out.setdefault((v.get("name") or "").lower(), Global(v, owner, constant, retained))
    return out


def _runs(resource: Element) -> set[str]:
    """The POU types the resource's tasks (and the resource itself) instantiate."""
    out = set()
    for holder in [resource, *resource.findall("task", PLCOPEN_NS)]:
        for inst in holder.findall("pouInstance", PLCOPEN_NS):
            out.add((inst.get("typeName") or "").lower())
    return out


class Globals:
    """Every global of the file, by scope."""

    def __init__(self, root: Element, users: dict[str, set[str]]) -> None:
        """``users``: POU (lower case) -> the POUs (lower case) that declare an instance of
        it (a program's function block instances)."""
        self.scopes: list[tuple[set[str], dict[str, Global]]] = []  # (POUs run, globals)
        self.everything: dict[str, Global] = {}
        instances = root.find("instances", PLCOPEN_NS)
        configs = instances.find("configurations", PLCOPEN_NS) if instances is not None else None
        for config in configs.findall("configuration", PLCOPEN_NS) if configs is not None else []:
            own = _globals_of(config, f"configuration '{config.get('name')}'")
            for resource in config.findall("resource", PLCOPEN_NS):
                mine = _globals_of(resource, f"resource '{resource.get('name')}'")
                self.scopes.append((_closure(_runs(resource), users), {**own, **mine}))
                for k, g in mine.items():
                    self.everything.setdefault(k, g)
            for k, g in own.items():
                self.everything.setdefault(k, g)

    def visible(self, pou: str) -> dict[str, Global]:
        """The globals POU ``pou`` reaches, by their name in lower case."""
        for runs, found in self.scopes:
            if pou.lower() in runs:
                return found
        return self.everything


def _closure(run: set[str], users: dict[str, set[str]]) -> set[str]:
    """The POUs run, and the function blocks their instances are of, and so on."""
    out, stack = set(run), list(run)
    while stack:
        p = stack.pop()
        for fb, owners in users.items():
            if p in owners and fb not in out:
                out.add(fb)
                stack.append(fb)
    return out
