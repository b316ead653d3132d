"""The console commands that change the plant (marked * in help; they need ``unlock PIN``
or a trusted console): set, force, unforce, pause, resume, cycle, init, reset, iocheck,
ack, reload. Plain functions ``(session, args) -> Reply``, dispatched through commands.COMMANDS;
``cycle`` returns a Pending (its reply comes once its scans have run).

Pause, stepping, iocheck and forces are held by the session that made them: each is
recorded with ``ConsoleService.hold`` in the same scan-thread call as the plant change, and
let go in the call that ends it.

Each command that changed the plant leaves one log line naming its console, after the
change is made (a refused command leaves none): one message template per command, so the
log's rate limit (logsetup.RateLimit) counts each command on its own.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from runtime.console.protocol import CYCLE_DETAIL_LINES, MAX_CYCLE, Pending, Reply
from runtime.engine.names import Catalogue, CommandError, Image, Signal, parse_value, printable
from runtime.language import ast as A

if TYPE_CHECKING:
    from runtime.console.session import Session

log = logging.getLogger(__name__)


def _state(session: Session) -> str:
    """The controller's state (running, paused, iocheck, fault...)."""
    return str(session.ctl.status()["state"])


def _two(session: Session, args: list[str], usage: str) -> tuple[Signal, Any]:
    """``NAME VALUE`` -> the name and its parsed value."""
    if len(args) != 2:
        raise CommandError(f"usage: {usage}")
    name = session.cat.resolve(args[0])
    return name, parse_value(name, args[1])


def cmd_set(session: Session, args: list[str]) -> Reply:
    name, value = _two(session, args, "set NAME VALUE")
    plant = session.plant
    if name.binding.startswith("<-"):
        raise CommandError(f"{name.text} is copied from {name.binding[3:]} before every "
                           f"scan: set that point, or force {name.text}")
    if name.text in session.cat.rewritten:  # held or not: a held chart's are not copied
        raise CommandError(f"{name.text} is written by its chart every scan: force it")
    writer = session.cat.written_by.get(name.text)

    def write() -> None:
        state = _state(session)
        if writer is not None and state in ("running", "stepping"):
            raise CommandError(f"{name.text} is written by {writer} every scan: force "
                               "it, or pause or 'iocheck on' first")
        if name.role == "point out" and state in ("fault", "halted"):
            raise CommandError(f"the controller is {state}: outputs are held off until "
                               "'ack'")
        plant.set(name.text, value)
    session.call(write)
    log.info("console %s: set %s = %s", session.name, name.text, name.show(value))
    return [f"{name.text} set to {name.show(value)}"]


def cmd_force(session: Session, args: list[str]) -> Reply:
    name, value = _two(session, args, "force NAME VALUE")
    if name.role in ("step", "step time", "driver health") or name.type is A.Type.STRING:
        raise CommandError(f"{name.text} cannot be forced (a {name.role}); force "
                           "inputs, outputs and variables")
    plant = session.plant

    def force() -> None:
        session.service.hold(f"force {name.text}", session)
        plant.force(name.text, value)
        if name.role not in ("point in", "point out"):
            plant.set(name.text, value)  # visible at once, even while paused
    session.call(force)
    log.warning("console %s: force %s = %s", session.name, name.text, name.show(value))
    return [f"{name.text} forced to {name.show(value)}"]


def cmd_unforce(session: Session, args: list[str]) -> Reply:
    if len(args) != 1:
        raise CommandError("usage: unforce NAME|all")
    if args[0] == "all":
        released = unforce_all(session)
        return [f"released {', '.join(released)}" if released else "nothing was forced"
                ], {"released": released}
    name = session.cat.resolve(args[0])
    plant = session.plant

    def release() -> None:
        plant.unforce(name.text)
        session.service.let_go(f"force {name.text}")
    session.call(release)
    log.info("console %s: force %s released", session.name, name.text)
    return [f"{name.text} released"], {"released": [name.text]}


def unforce_all(session: Session) -> list[str]:
    """Release every force (``unforce all``, ``lock``); the names released."""
    plant = session.plant

    def release() -> list[str]:
        names = plant.forced_names()
        plant.unforce(None)
        session.service.let_go_forces()
        return names
    released = session.call(release)
    if released:
        log.warning("console %s: every force released (%s)", session.name,
                    ", ".join(released))
    return released


def cmd_pause(session: Session, args: list[str]) -> Reply:
    plant = session.plant

    def do() -> str:
        state = _state(session)
        if state == "iocheck":
            raise CommandError("iocheck on: the charts are stopped already")
        session.service.hold("pause", session)  # taken again: its time starts again
        return "already paused" if plant.pause() else "paused"
    done = session.call(do)
    log.info("console %s: pause: charts held%s", session.name,
             " (already paused)" if done == "already paused" else "")
    return [done + ": charts hold, I/O still scanned; 'cycle N' steps, 'resume' goes on"]


def cmd_resume(session: Session, args: list[str]) -> Reply:
    plant = session.plant

    def do() -> str:
        session.service.let_go("pause", "cycle")
        return "resumed" if plant.resume() else "not paused"
    done = session.call(do)
    if done == "resumed":
        log.info("console %s: resume: charts run", session.name)
    return [done]


def cmd_cycle(session: Session, args: list[str]) -> Pending:
    if len(args) > 1:
        raise CommandError("usage: cycle [N]")
    try:
        n = int(args[0]) if args else 1
    except ValueError:
        raise CommandError(f"bad value '{printable(args[0])}': expected a number of "
                           "scans") from None
    if not 1 <= n <= MAX_CYCLE:
        raise CommandError(f"bad value {n}: cycle N runs 1 to {MAX_CYCLE} scans")
    return _Stepping(session, n)


class _Stepping(Pending):
    """``cycle N`` while its scans run: the scan thread copies the image after each of
    them; the reply is built when they have run (or when Ctrl-C stops them, or after
    2 s plus twice their duration, which cancels the stepping). The thread serving the
    session serves the others meanwhile, and sees at once when this one ends."""

    command = "cycle"

    def __init__(self, session: Session, n: int) -> None:
        self.session, self.n = session, n
        plant, cat = session.plant, session.cat
        self.images: list[Image] = []
        self.done = threading.Event()
        self.interrupted = False
        images, done = self.images, self.done

        def on_scan(scan: int) -> None:  # scan thread
            images.append(cat.capture(scan))
            if not plant.stepping:
                done.set()
        self.on_scan = on_scan

        def start() -> Image:
            state = _state(session)
            if state != "paused":
                raise CommandError(f"cycle runs while paused; the controller is {state}"
                                   + (": pause first" if state == "running" else ""))
            session.service.hold("pause", session)  # the stepping session answers for both
            session.service.hold("cycle", session)
            plant.step(n)
            session.ctl.add_listener(on_scan)
            return cat.capture(-1)
        self.before = session.call(start)
        self.deadline = time.monotonic() + 2.0 + 2 * n * plant.cycle_ns / 1e9

    def ready(self) -> bool:
        return self.done.is_set() or self.interrupted or time.monotonic() >= self.deadline

    def interrupt(self) -> None:
        self.interrupted = True

    def abandon(self) -> None:
        self.session.ctl.remove_listener(self.on_scan)  # its end halts (session_ended)

    def finish(self) -> Reply:
        session, n = self.session, self.n
        ctl = session.ctl

        def cancel() -> int:  # scan thread: the steps that ran, and no more of them
            plant = ctl.plant
            ran = n - max(0, plant.steps_left) if plant.stepping else n
            plant.step(0)
            return ran
        try:
            ran = n if self.done.is_set() else ctl.call(cancel)
        finally:
            ctl.remove_listener(self.on_scan)
            session.service.let_go("cycle")
        images = self.images[:ran]
        log.info("console %s: cycle %d: ran scans %s", session.name, n,
                 f"{images[0].scan}..{images[-1].scan}" if images else "none")
        if ran == n:
            return _cycle_report(session.cat, n, self.before, images)
        if self.interrupted:
            lines, data = _cycle_report(session.cat, n, self.before, images)
            raise CycleStopped(f"cycle stopped by Ctrl-C after {ran} of {n} scans",
                               lines, data)
        raise CommandError(f"the scans did not run (controller {_state(session)}); "
                           "stepping cancelled")


class CycleStopped(CommandError):
    """``cycle N`` stopped by Ctrl-C: the report of the scans that ran comes before the
    error line; JSON: ``scans``, ``per_scan``, ``changed`` as for a complete one."""

    def __init__(self, reason: str, lines: list[str], data: dict[str, Any]) -> None:
        super().__init__(reason)
        self.lines = lines
        self.data = data


def _cycle_report(cat: Catalogue, n: int, before: Image, images: list[Image]
                  ) -> tuple[list[str], dict[str, Any]]:
    """What ``cycle N`` changed: scan by scan (the first CYCLE_DETAIL_LINES), then in all."""
    names = cat.traced
    steps = [x for x in names if x.role == "step"]
    prev = {x.text: x.read(before) for x in names}
    first = prev
    lines = [f"ran {len(images) if len(images) < n else n}"
             + (f" of {n}" if len(images) < n else "") + " scan(s)"
             + (f" ({images[0].scan}..{images[-1].scan})" if images else "")]
    per_scan = []
    for img in images:
        cur = {x.text: x.read(img) for x in names}
        changed = {k: v for k, v in cur.items() if prev[k] != v}
        per_scan.append({"scan": img.scan, "changed": {
            k: cat.names[k].plain(v) for k, v in changed.items()}})
        if changed and len(lines) < CYCLE_DETAIL_LINES:
            lines.append(f"scan {img.scan}: " + _changes(cat, changed, prev, steps))
        elif changed and len(lines) == CYCLE_DETAIL_LINES:
            lines.append("... (more scans changed; the total follows)")
        prev = cur
    total = {k: v for k, v in prev.items() if first[k] != v}
    if sum(1 for p in per_scan if p["changed"]) > 1 and total:
        lines.append("in all: " + _changes(cat, total, first, steps))
    if not total and not any(p["changed"] for p in per_scan):
        lines.append("nothing changed")
    return lines, {"scans": len(images), "per_scan": per_scan,
                   "changed": {k: cat.names[k].plain(v) for k, v in total.items()}}


def _changes(cat: Catalogue, changed: dict[str, Any], before: dict[str, Any],
             steps: list[Signal]) -> str:
    """``tester1 gsParado -> gsAbrir; tester1.oAbrir 0 -> 1, ...``"""
    parts = []
    for inst in cat.groups:
        mine = [x.text for x in steps if x.text.startswith(inst + ".")]
        if not any(k in changed for k in mine):
            continue
        was = [k.split(".")[1] for k in mine if before[k]]
        now = [k.split(".")[1] for k in mine if changed.get(k, before[k])]
        parts.append(f"{inst} {','.join(was) or '-'} -> {','.join(now) or '-'}")
    names = cat.names
    others = [f"{k} {names[k].show(before[k])} -> {names[k].show(v)}"
              for k, v in changed.items() if names[k].role != "step"]
    return "; ".join(parts + ([", ".join(others)] if others else []))


def _pulse(session: Session, args: list[str], flag: str) -> Reply:
    plant = session.plant
    if len(args) != 1 or args[0] not in plant.instances:
        given = f"; no instance '{printable(args[0])}'" if args else ""
        raise CommandError(f"usage: {flag[3:].lower()} INSTANCE{given} (one of "
                           f"{' '.join(plant.instances)})")

    def do() -> str:
        state = _state(session)
        if state == "iocheck":
            raise CommandError("iocheck on: the charts are stopped")
        plant.pulse(args[0], flag)
        return state
    state = session.call(do)
    log.info("console %s: %s %s: %s pulsed", session.name, flag[3:].lower(), args[0], flag)
    when = " at the next scan" if state != "paused" else " at the next scan ('cycle' " \
                                                          "or 'resume': paused now)"
    return [f"{flag} pulsed on {args[0]}{when}"]


def cmd_init(session: Session, args: list[str]) -> Reply:
    return _pulse(session, args, "SFCInit")


def cmd_reset(session: Session, args: list[str]) -> Reply:
    return _pulse(session, args, "SFCReset")


def cmd_iocheck(session: Session, args: list[str]) -> Reply:
    if args not in (["on"], ["off"]):
        raise CommandError("usage: iocheck on|off")
    plant, ctl = session.plant, session.ctl
    if args[0] == "on":
        def enter() -> list[str]:
            state = _state(session)
            if state == "fault":
                raise CommandError("the controller is in fault: 'ack' it first")
            session.service.hold("iocheck", session)
            if state == "iocheck":
                return []
            released = plant.forced_names()
            plant.unforce(None)  # outputs all off means forced ones too
            session.service.let_go_forces()
            if state == "halted":
                # back to the bench after a previous iocheck: the charts were waiting
                # for ack; acknowledge and re-enter in the same boundary, so no scan runs
                ctl.ack()
            # iocheck ends a pause: its end halts, and 'ack' restarts the charts running
            plant.resume()
            session.service.let_go("pause", "cycle")
            plant.set_iocheck(True)
            return released
        released = session.call(enter)
        log.warning("console %s: iocheck on: charts stopped, every output off%s",
                    session.name, f"; released forces: {', '.join(released)}"
                    if released else "")
        lines = ["iocheck: charts stopped, every output off. 'set DRIVER.POINT 1' drives "
                 "one output, 'watch' shows physical inputs with their logical value, "
                 "'iocheck off' ends"]
        if released:
            lines.append(f"released forces: {', '.join(released)}")
        return lines, {"released": released}

    def leave() -> None:
        if not plant.iocheck:
            raise CommandError("not in iocheck")
        plant.set_iocheck(False)
        session.service.let_go("iocheck")
        # the same boundary: no scan may run the charts between the two
        ctl.require_ack("iocheck ended: 'ack' restarts the charts from their initial "
                        "situation")
    session.call(leave)
    log.warning("console %s: iocheck off: outputs off until ack", session.name)
    return ["iocheck off: every output off; 'ack' restarts the charts from their "
            "initial situation"]


def cmd_ack(session: Session, args: list[str]) -> Reply:
    def do() -> tuple[str, str, str | None]:
        status = session.ctl.status()  # what is acknowledged, for the log
        done = session.ctl.ack()  # releases every force (Daemon._ack)
        session.service.let_go_forces()
        return done, str(status["state"]), status.get("fault")
    done, state, reason = session.call(do)
    if reason:
        log.warning("console %s: ack (%s: %s): %s", session.name, state, reason, done)
    else:
        log.info("console %s: ack: %s", session.name, done)
    return [done]


class ReloadRefused(CommandError):
    """``reload`` did not change anything: the reply lists each reason on its own line
    (``refused: ...``) before its error line; JSON: ``refusals`` and ``lines``."""

    def __init__(self, reasons: list[str], lines: list[str], data: dict[str, Any]) -> None:
        if len(reasons) == 1:
            super().__init__(f"reload refused: {reasons[0]}")
            self.lines = lines
        else:
            super().__init__(f"reload refused ({len(reasons)} reasons): nothing changed")
            self.lines = lines + [f"refused: {r}" for r in reasons]
        self.data = data


def _reload_args(args: list[str]) -> tuple[bool, bool, list[str]]:
    """``[--force] [--restart INSTANCE]... [--back]`` -> force, back, restart."""
    usage = "usage: reload [--force] [--restart INSTANCE]... [--back]"
    force = back = False
    restart: list[str] = []
    words = iter(args)
    for w in words:
        if w == "--force":
            force = True
        elif w == "--back":
            back = True
        elif w == "--restart":
            name = next(words, None)
            if name is None:
                raise CommandError(f"{usage}; --restart names an instance")
            restart.append(name)
        else:
            raise CommandError(f"{usage}; not '{printable(w)}'")
    return force, back, restart


def cmd_reload(session: Session, args: list[str]) -> Reply:
    """Online change: the controller loads its plant and charts again and swaps the
    programs between two scans (docs/online-change.md). Blocks this session until done."""
    force, back, restart = _reload_args(args)
    result = session.ctl.reload(restart=restart, force=force, back=back)
    data = result.as_dict()
    what = "reload --back" if back else "reload"
    if not result.applied:
        log.warning("console %s: %s refused: %s", session.name, what,
                    "; ".join(result.refusals))
        raise ReloadRefused(result.refusals, [f"  {x}" for x in result.lines], data)
    log.warning("console %s: %s applied: %s", session.name, what, result.summary)
    lines = [f"{what} applied in {result.swap_ms:.1f} ms (loaded in {result.load_ms:.0f} ms, "
             f"prepared in {result.prepare_ms:.0f} ms): {len(result.lines)} change(s)"]
    lines += [f"  {x}" for x in result.lines]
    lines += [f"restarted from its initial situation: {x}" for x in result.restarted]
    lines += [f"driver reopened (its outputs were off meanwhile): {x}"
              for x in result.reopened]
    return lines, data


def last_reload_text(last: dict[str, Any]) -> str:
    """``status``'s line for the last applied change."""
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(last["time"]))
    return f"last reload{' (--back)' if last['back'] else ''} at {when}: {last['summary']}"
