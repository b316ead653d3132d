"""One base class for the project's errors: every exception class that runtime/ defines
derives from SoftplcError (drivers/ cannot import runtime and keep their own)."""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import runtime
from runtime.errors import Loc, SoftplcError, SourceError

#: exceptions used for control flow inside one module, never raised to a caller
INTERNAL = {"runtime.language.typecheck.TempUnknown"}


def runtime_exceptions() -> dict[str, type[BaseException]]:
    found: dict[str, type[BaseException]] = {}
    for info in pkgutil.walk_packages(runtime.__path__, "runtime."):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if (inspect.isclass(obj) and issubclass(obj, BaseException)
                    and obj.__module__ == info.name):
                found[f"{info.name}.{name}"] = obj
    return found


def test_every_runtime_error_derives_from_the_base() -> None:
    found = runtime_exceptions()
    assert "runtime.engine.commands.CommandRefused" in found  # the walk sees subpackages
    strays = sorted(k for k, cls in found.items()
                    if not issubclass(cls, SoftplcError) and k not in INTERNAL)
    assert strays == [], f"errors outside SoftplcError: {strays}"


def test_a_user_facing_error_renders_its_place() -> None:
    err = SourceError(Loc("plant.yaml", 7, 13), "unknown driver or instance 'exp2'")
    assert isinstance(err, SoftplcError)
    assert str(err) == "plant.yaml:7:13: error: unknown driver or instance 'exp2'"
