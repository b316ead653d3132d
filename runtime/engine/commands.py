"""What the controller answers to a command it will not carry out: shared by the daemon,
which raises it, and the console, which reports it."""

from __future__ import annotations

from runtime.errors import SoftplcError


class CommandRefused(SoftplcError):
    """A request the controller will not carry out now; the message says why.

    Examples: ``ack`` while the lost I/O node is still missing; ``ack`` with nothing to
    acknowledge."""
