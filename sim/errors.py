"""User-facing errors.

A ``WrinklesInputError`` is a problem with something the user supplied (a file, a name, an
array). The CLI prints its message on one line and exits with status 2, without a traceback
(ARCHITECTURE.md). Messages name the file (when there is one) and what is wrong, in our words:
a library's own message can advise loading the file unsafely (numpy's ``allow_pickle``, torch's
``weights_only=False``), which we never do, so such text is not passed on (``NEVER_UNPICKLED``).
"""

from __future__ import annotations

import os

NEVER_UNPICKLED = "wrinkles never loads pickled Python objects (unpickling can run any code)"
"""The end of a refusal of a file that holds pickled objects (a checkpoint or an array file
written with Python objects in it): what the file has that we do not read, and why."""


class WrinklesInputError(ValueError):
    """Bad user input: one-line message naming the file and the problem."""

    def __init__(self, message: str, *, path: str | os.PathLike | None = None):
        self.path = None if path is None else os.fspath(path)
        msg = " ".join(str(message).split())  # always one line
        super().__init__(f"{self.path}: {msg}" if self.path else msg)
