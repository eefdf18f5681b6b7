"""Log lines are capped: a stranger's payload quoted in a message cannot flood the log."""

from __future__ import annotations

import io
import logging

import pytest

from hub.logs import CapFilter, cap_text, install_log_cap


def test_text_up_to_the_cap_is_kept_and_longer_text_says_how_long_it_was():
    assert cap_text("abc", 3) == "abc"
    assert cap_text("abcdef", 3) == "abc… (6 chars)"


@pytest.fixture
def root_stream():
    """The root logger writing to a string, as logging.basicConfig sets it up; restored after."""
    root = logging.getLogger()
    saved = root.handlers[:], root.filters[:], root.level
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(name)s %(levelname)s: %(message)s"))
    root.handlers[:] = [handler]
    root.setLevel(logging.INFO)
    yield stream
    # The cap also went on pytest's own handlers, which live on through the session
    # (added to the root for each phase of each test): it must not cut later tests' logs.
    for target in {*root.handlers, *saved[0]}:
        for cap in [f for f in target.filters if isinstance(f, CapFilter)]:
            target.removeFilter(cap)
    root.handlers[:], root.filters[:] = saved[0], saved[1]
    root.setLevel(saved[2])


def test_a_589005_character_message_of_any_logger_is_written_as_one_short_line(root_stream):
    install_log_cap(2000)
    logging.getLogger("hub.loop").warning("dropped %s", "x" * 589_000)
    line = root_stream.getvalue()
    assert line.count("\n") == 1 and len(line) < 2100
    assert line.startswith("hub.loop WARNING: dropped xxx")
    assert line.rstrip().endswith("… (589008 chars)")


def test_short_lines_are_unchanged(root_stream):
    install_log_cap(2000)
    logging.getLogger("x").info("step %d of %d", 3, 10)
    assert root_stream.getvalue() == "x INFO: step 3 of 10\n"


def test_a_traceback_is_capped_too(root_stream):
    install_log_cap(500)
    try:
        raise ValueError("y" * 10_000)
    except ValueError:
        logging.getLogger("x").exception("failed")
    text = root_stream.getvalue()
    assert text.startswith("x ERROR: failed\nTraceback") and len(text) < 700
    assert "chars)" in text


def test_installing_again_replaces_the_cap(root_stream):
    install_log_cap(2000)
    install_log_cap(10)
    logging.getLogger("x").info("z" * 50)
    assert root_stream.getvalue() == "x INFO: zzzzzzzzzz… (50 chars)\n"
    assert sum(isinstance(f, CapFilter) for f in logging.getLogger().handlers[0].filters) == 1
