"""Log lines capped at a length: a message quoting a stranger's payload cannot flood the log.

A record's message (with its arguments filled in), its traceback and its stack are each
cut to ``max_chars`` characters, with ``… (N chars)`` appended saying how long it was.
Install once, after the handlers are set up (``logging.basicConfig``)::

    logging.basicConfig(...)
    install_log_cap()
"""

from __future__ import annotations

import logging

MAX_LOG_CHARS = 2_000


def cap_text(text: str, max_chars: int = MAX_LOG_CHARS) -> str:
    """``text`` if it is at most ``max_chars`` long, else its start and ``… (N chars)``.

    Parameters
    ----------
    text : str
        The text to cap.
    max_chars : int
        Characters kept; N is the length of the whole ``text``.
    """
    if len(text) <= max_chars:
        return text
    return f"{text[:max_chars]}… ({len(text)} chars)"


class CapFilter(logging.Filter):
    """A filter that caps a record's message, traceback and stack text in place (and lets
    every record through).

    Parameters
    ----------
    max_chars : int
        Characters kept of each; the rest is replaced by ``… (N chars)``.
    """

    def __init__(self, max_chars: int = MAX_LOG_CHARS):
        super().__init__()
        if max_chars < 1:
            raise ValueError("max_chars must be >= 1")
        self.max_chars = max_chars

    def filter(self, record: logging.LogRecord) -> bool:
        """Cap ``record``'s message, traceback and stack text in place; always True."""
        message = record.getMessage()
        if len(message) > self.max_chars:
            record.msg, record.args = cap_text(message, self.max_chars), None
        if record.exc_info and not record.exc_text:
            # Formatters use exc_text when set (and cache it there themselves).
            record.exc_text = logging.Formatter().formatException(record.exc_info)
        if record.exc_text:
            record.exc_text = cap_text(record.exc_text, self.max_chars)
        if record.stack_info:
            record.stack_info = cap_text(record.stack_info, self.max_chars)
        return True


def install_log_cap(max_chars: int = MAX_LOG_CHARS) -> CapFilter:
    """Cap every line the root logger's handlers write (records of all loggers reach them).

    Call after the handlers exist; a handler added later is not covered. Installing again
    replaces the cap."""
    root = logging.getLogger()
    cap = CapFilter(max_chars)
    for target in [root, *root.handlers]:
        for old in [f for f in target.filters if isinstance(f, CapFilter)]:
            target.removeFilter(old)
        target.addFilter(cap)
    return cap
