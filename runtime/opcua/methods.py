"""The plant's OPC UA methods (docs/opcua.md, "Methods"), and who calls them.

- Each instance object has ``Acknowledge`` (SFCQuitError for one scan: the chart's
  SFCError acknowledged; refused when there is none), ``Reset`` (SFCReset for one scan),
  ``Pause`` and ``Resume`` (SFCPause set and cleared); the Controller object has ``Ack``
  (the console's ``ack``). No arguments, no results. A call is first held to Part 4
  (runtime/opcua/calls.py: the method of that object, no argument): a refused call runs
  nothing and is one log line.
- Only a writer (runtime/opcua/security.py) may call them; anyone else gets
  BadUserAccessDenied, and reads UserExecutable false on them. The controller applies
  them between two scans (the feed's ``call``: runtime/controller/feed.py) and its refusal
  (nothing to acknowledge, a flag bound to a point) is the call's BadInvalidState.
- Each call is logged, by the server and by the controller, with the caller's identity
  (user name or certificate subject, and address): asyncua hands a method no session,
  so every session's Call service sets ``CALLER`` (a context variable of the task that
  runs the call).
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from contextvars import ContextVar
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.crypto.permission_rules import User

from runtime.controller.feed import METHODS
from runtime.engine.names import printable
from runtime.opcua.calls import refusal
from runtime.opcua.space import nid, qname

if TYPE_CHECKING:
    from runtime.opcua.server import PlantServer

log = logging.getLogger(__name__)

#: the user and the peer address of the session whose Call is being served
CALLER: ContextVar[tuple[User, str] | None] = ContextVar("softplc_opcua_caller",
                                                          default=None)
#: the Controller object's methods
CONTROLLER_METHODS = ("Ack",)


def identity(caller: tuple[User, str] | None) -> str:
    """How the log names a caller: ``operator (127.0.0.1:50432)``."""
    if caller is None:
        return "the server itself"
    user, peer = caller
    return f"{user.name or 'anonymous'} ({peer})"


def peer_text(name: Any) -> str:
    """A session's name in asyncua is its client's (address, port)."""
    if isinstance(name, tuple) and len(name) >= 2:
        return f"{name[0]}:{name[1]}"
    return str(name)


def track_callers(server: Any) -> None:
    """Have every client session's Call service refuse what Part 4 refuses (calls.py),
    without running it, and set ``CALLER`` while the rest runs (in the order asked)."""
    iserver = server.iserver
    aspace = iserver.aspace
    plain = iserver.create_session

    def create_session(name: Any, *args: Any, **kwargs: Any) -> Any:
        session = plain(name, *args, **kwargs)
        call = session.call

        async def traced(params: list[ua.CallMethodRequest]) -> Any:
            results: list[ua.CallMethodResult | None] = [
                refusal(aspace, session, req) for req in params]
            run = [req for req, res in zip(params, results, strict=True) if res is None]
            if len(run) < len(params):
                log.info("opcua: %s: %s", identity((session.user, peer_text(session.name))),
                         "; ".join(_refused(req, res) for req, res in
                                   zip(params, results, strict=True) if res is not None))
            if run:
                token = CALLER.set((session.user, peer_text(session.name)))
                try:
                    done = iter(await call(run))
                finally:
                    CALLER.reset(token)
                results = [res if res is not None else next(done) for res in results]
            return results
        session.call = traced
        return session
    iserver.create_session = create_session


def _refused(req: ua.CallMethodRequest, res: ua.CallMethodResult) -> str:
    """``call of ns=2;s=t1.Pause on ns=2;s=t2 refused: BadMethodInvalid``"""
    return (f"call of {printable(req.MethodId.to_string(), 80)} on "
            f"{printable(req.ObjectId.to_string(), 80)} with {len(req.InputArguments or [])} "
            f"argument(s) refused: {res.StatusCode.name}")


class Methods:
    """The methods of one server's plant objects (``build``, after the objects exist)."""

    def __init__(self, ps: PlantServer) -> None:
        self.ps = ps
        #: every method node of ours (UserExecutable answers per session)
        self.nodes: set[ua.NodeId] = set()

    async def build(self) -> None:
        space = self.ps.space
        for name, obj in space.instances.items():
            for method in METHODS:
                node = await obj.add_method(nid(f"{name}.{method}"), qname(method),
                                            self._handler(name, method))
                self.nodes.add(node.nodeid)
        assert space.controller is not None
        for method in CONTROLLER_METHODS:
            node = await space.controller.add_method(nid(f"controller.{method}"),
                                                     qname(method),
                                                     self._handler("controller", method))
            self.nodes.add(node.nodeid)

    def _handler(self, target: str, method: str
                 ) -> Callable[..., Awaitable[ua.StatusCode | list[Any]]]:
        mine = nid(target)

        async def call(parent: ua.NodeId, *args: Any) -> ua.StatusCode | list[Any]:
            # calls.py refused these already; said again here, where the method runs
            if parent != mine:
                return ua.StatusCode(ua.StatusCodes.BadMethodInvalid)
            if args:
                return ua.StatusCode(ua.StatusCodes.BadTooManyArguments)
            caller = CALLER.get()
            who = identity(caller)
            if caller is None or not self.ps.may_write(caller[0]):
                log.warning("opcua: %s.%s refused to %s: writers only", target, method, who)
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            ok, text, code = await self.ps.ask("call", target, method, who)
            if not ok:  # the one line of a refusal (the controller logs only what it did)
                log.info("opcua: %s called %s.%s: refused (%s): %s", who, target, method,
                         code, text)
                return ua.StatusCode(getattr(ua.StatusCodes, code,
                                             ua.StatusCodes.BadInvalidState))
            log.info("opcua: %s called %s.%s: %s", who, target, method, text)
            return []
        return call

    def executable(self, node: ua.NodeId, user: User | None) -> bool | None:
        """UserExecutable of ``node`` for ``user`` (None: not one of ours)."""
        if node not in self.nodes:
            return None
        return user is not None and self.ps.may_write(user)
