"""compiler/blocks.py implements exactly the signatures language/signatures.py declares."""

from __future__ import annotations

import pytest

from runtime.compiler.blocks import BLOCKS, SeedTimer
from runtime.language import ast as A
from runtime.language.signatures import FB_MEMBERS, TIMER_METHODS

PYTHON_TYPE = {A.Type.BOOL: bool, A.Type.INT: int, A.Type.TIME: int}


def test_every_declared_block_is_implemented() -> None:
    assert set(BLOCKS) == set(FB_MEMBERS)


@pytest.mark.parametrize("kind", sorted(FB_MEMBERS))
def test_members_and_their_types(kind: str) -> None:
    cls = BLOCKS[kind]
    slots: tuple[str, ...] = cls.__slots__  # type: ignore[attr-defined]
    public = {s for s in slots if not s.startswith("_")}
    assert public == set(FB_MEMBERS[kind])
    block = cls()
    for member, (mtype, _) in FB_MEMBERS[kind].items():
        assert type(getattr(block, member)) is PYTHON_TYPE[mtype], member
    assert callable(block.update)


def test_seed_timer_methods() -> None:
    for method in TIMER_METHODS:
        assert callable(getattr(SeedTimer, method.lower()))
