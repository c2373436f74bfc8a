"""How a command is stopped: SIGTERM unwinds the job as Ctrl-C does, so that its temporary
outputs are removed (``pipelines.outputs.OutputSet``) and the exit status says which it was."""

from __future__ import annotations

import signal
import threading


class Terminated(KeyboardInterrupt):
    """SIGTERM (a scheduler or ``kill``), raised where the job is, so that it unwinds as an
    interrupt does: its temporary outputs removed (``pipelines.outputs.OutputSet``)."""


def interruption(e: KeyboardInterrupt) -> tuple[str, int]:
    """How a command was stopped, in a word, and its exit status: SIGTERM ('terminated', 143)
    or Ctrl-C ('interrupted', 130)."""
    return ("terminated", 143) if isinstance(e, Terminated) else ("interrupted", 130)


def _raise_terminated(signum, frame):
    raise Terminated()


NOT_INSTALLED = object()
"""What ``terminate_as_interrupt`` returns where it installed nothing."""


def terminate_as_interrupt():
    """Route SIGTERM to ``Terminated`` while a command runs; the handler it replaced (to put
    back with ``restore_sigterm``), or ``NOT_INSTALLED`` where signals cannot be handled (not
    the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return NOT_INSTALLED
    return signal.signal(signal.SIGTERM, _raise_terminated)


def restore_sigterm(previous) -> None:
    """Put back the SIGTERM handler ``terminate_as_interrupt`` replaced."""
    if previous is not NOT_INSTALLED:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
