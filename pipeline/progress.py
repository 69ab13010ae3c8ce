"""How far a long stage has come: a bar on a terminal, log lines under make.

A stage that may run for more than a few seconds reports its progress through
:class:`Progress`: on a terminal (stderr a TTY) a bar redrawn in place; otherwise
(under make, in a batch log) a log line when a tenth more is done or every
:data:`EVERY` seconds, whichever comes later, so a log shows which stage, which part and
how far without a line per step. A stage of several named steps (remesh's classifying,
cleaning and remeshing) reports through :class:`Steps`, which the library calls as
``progress(what, done, total, detail)``. Work done in forked workers (a file's flowers
bloomed side by side) is shown by the parent: each worker posts how far its task has got
on a :class:`Board` shared at the fork, and the parent's :class:`Progress` reads it.
"""

from __future__ import annotations

import logging
import multiprocessing
import sys
import time

log = logging.getLogger("bloom")

EVERY = 10.0  #: seconds between log lines at least (no bar)
WIDTH = 30  #: characters of the bar
#: in a forked worker: ``post(text, share)``, where its :class:`Progress` reports go (to
#: the parent's :class:`Board`) instead of a bar or a log line; None elsewhere
_POST = None


class Progress:
    """``with Progress(total, "simulate") as p: ... p.update(n)``; ``p.note(text)`` names
    what is being worked on (a part, a petal). ``show``: force the bar on (True) or off
    (False); default: on when stderr is a terminal. ``quiet``: no log lines either."""

    def __init__(self, total: float, label: str, show: bool | None = None, quiet: bool = False,
                 heartbeat: float | None = None):
        self.total, self.label = max(float(total), 1e-300), label
        self.post = _POST  # (in a forked worker: its parent shows it)
        self.bar = self.post is None and (sys.stderr.isatty() if show is None else show)
        self.quiet = quiet or not log.isEnabledFor(logging.INFO)
        self.done, self.what = 0.0, ""
        self.start = self.last = time.monotonic()
        self.logged = 0.0  #: fraction at the last log line
        #: no bar: a log line at least this often (seconds), however little was done
        self.heartbeat = heartbeat

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> bool:
        if self.bar:
            sys.stderr.write("\n")
            sys.stderr.flush()
        return False

    def note(self, what: str) -> None:
        self.what = what
        self._show()

    def update(self, n: float = 1) -> None:
        self.done = min(self.done + n, self.total)
        self._show()

    def reach(self, done: float, what: str) -> None:
        """``done`` of the total so far (never less than before), working on ``what``."""
        self.done, self.what = min(max(self.done, done), self.total), what
        self._show()

    def _show(self) -> None:
        now = time.monotonic()
        share = self.done / self.total
        if self.post is not None:
            self.post(f"{self.label}{': ' + self.what if self.what else ''}", share)
            return
        beat = self.heartbeat is not None and now - self.last >= self.heartbeat
        if self.bar:
            filled = int(WIDTH * share)
            eta = (now - self.start) * (1 - share) / share if share > 0 else 0.0
            sys.stderr.write(f"\r{self.label} [{'#' * filled}{'-' * (WIDTH - filled)}] "
                             f"{100 * share:3.0f}%  {eta:5.0f} s left  {self.what[:40]:40s}")
            sys.stderr.flush()
        elif not self.quiet and (beat or now - self.last >= EVERY
                                 and share - self.logged >= 0.1 - 1e-12):
            log.info("%s: %.0f%% done after %.0f s%s", self.label, 100 * share, now - self.start,
                     f" ({self.what})" if self.what else "")
            self.last, self.logged = now, share


def doing(text: str) -> None:
    """In a forked worker: tell the parent what it is doing where no :class:`Progress`
    counts it (a bud search); elsewhere nothing (the log says it)."""
    if _POST is not None:
        _POST(text, -1.0)


class Board:
    """How far each of ``count`` tasks run in forked workers has got, for the parent to
    show: a share done (-1: not known; NaN: not started) and a short text per task, in
    memory shared at the fork (created before the pool is). A worker calls
    :meth:`serve` for its task ``k`` (its :class:`Progress` bars then post here)."""

    WIDE = 100  #: bytes of a task's text

    def __init__(self, count: int):
        ctx = multiprocessing.get_context("fork")
        self._share = ctx.Array("d", [float("nan")] * max(count, 1), lock=False)
        self._text = ctx.Array("c", self.WIDE * max(count, 1), lock=False)

    def serve(self, k: int) -> None:
        """In a worker, for its task ``k``: its progress is posted here."""
        global _POST

        def post(text: str, share: float) -> None:
            raw = text.encode()[:self.WIDE].ljust(self.WIDE, b"\0")
            self._text[k * self.WIDE:(k + 1) * self.WIDE] = raw
            self._share[k] = share

        _POST = post
        post("starting", 0.0)

    def read(self, tasks) -> tuple[float, str]:
        """Of ``tasks`` (not done yet): the sum of their shares done, and what the ones
        started are doing (``"3: simulate flower 3 45%"``, joined)."""
        total, said = 0.0, []
        for k in tasks:
            share = self._share[k]
            if share != share:  # (NaN: not started)
                continue
            text = bytes(self._text[k * self.WIDE:(k + 1) * self.WIDE]).rstrip(b"\0").decode(
                errors="replace")
            total += max(share, 0.0)
            said.append(f"{text}{f' {100 * share:.0f}%' if share >= 0 else ''}")
        return total, "; ".join(said)


class Steps:
    """How far a stage of several named steps has got (remesh: classifying parts, cleaning
    petal parts, remeshing petals; axis: petal axes), as ``steps(what, done, total,
    detail="")`` calls from the library. On a terminal, a :class:`Progress` bar per step;
    otherwise (under make, in a log) a line when a step starts and at most every
    ``every`` seconds after, saying the stage, the input (``where``), the step, how far
    and (``detail``) which part. Nothing for the first ``quiet`` seconds, so a quick run
    prints no progress at all. ``close()`` ends the bar (also as a context manager)."""

    def __init__(self, stage: str, where: str, every: float = 5.0, quiet: float = 2.0,
                 show: bool | None = None):
        self.stage, self.where, self.every, self.quiet = stage, where, every, quiet
        self.tty = sys.stderr.isatty() if show is None else show
        self.start = self.last = time.monotonic()
        self.what, self.done, self.bar = None, 0, None

    def __enter__(self) -> Steps:
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def __call__(self, what: str, done: int, total: int, detail: str = "") -> None:
        now = time.monotonic()
        if now - self.start < self.quiet:
            self.what = what
            return
        if self.tty:
            if what != self.what or self.bar is None:
                self.close()
                self.bar = Progress(total, f"{self.stage}: {what}", show=True, quiet=True)
                self.done = 0
            self.bar.what = detail
            self.bar.update(max(done - self.done, 0))
            self.done = done
        elif what != self.what or now - self.last >= self.every:
            part = f", {detail}" if detail else ""
            share = f" ({100.0 * done / total:.0f}%)" if total else ""
            log.info("%s: %s: %s: %d of %d%s%s", self.stage, self.where, what, done, total,
                     share, part)
            self.last = now
        self.what = what

    def close(self) -> None:
        """End the step's bar, if one is drawn."""
        if self.bar is not None:
            self.bar.__exit__(None, None, None)
            self.bar = None
