"""The Khepera serial protocol as bytes: commands made, reply lines checked and parsed.

No I/O here: :mod:`adapters.khepera.link` sends and reads, the emulator answers. Facts from
``shared/reference/devices.md``: ASCII commands ending in ``\\r``; the reply starts with the
command's letter in lower case, its fields comma-separated, and ends with ``\\r\\n``.

Two dialects:

* ``khepera2`` (K-Team Khepera II): plain integers, ``N`` answers 8 proximity values; the
  position counters are set with ``G`` and read with ``H``.
* ``khepera3`` (K-Team Khepera III, its user manual v2.2): integers carry a type prefix on
  the way out (``D,l20000,l20000``); ``N`` answers 11 IR values (9 around the body, 2 on
  the ground) and a time stamp; the counters are set with ``I`` and read with ``R`` (its
  ``G`` and ``H`` are the ultrasound and the PID set-up).
"""

from __future__ import annotations

from dataclasses import dataclass

DIALECTS = ("khepera2", "khepera3")

#: what an unknown command gets back from the robot's firmware and from the emulator
UNKNOWN_COMMAND_REPLY = b"Command not found\r\n"

#: fields of each reply after its letter (None: not checked; strings for ``b``)
REPLY_FIELDS = {
    "khepera2": {"B": 2, "D": 0, "E": 2, "G": 0, "H": 2, "N": 8, "O": 8, "L": 0},
    "khepera3": {"B": 2, "D": 0, "E": 2, "I": 0, "R": 2, "N": 12, "O": 12},
}
#: proximity sensors around the body, first in ``N``'s reply
N_PROXIMITY = {"khepera2": 8, "khepera3": 9}
#: the commands that set and read the wheels' position counters
COUNTER_COMMANDS = {"khepera2": ("G", "H"), "khepera3": ("I", "R")}


class ReplyError(Exception):
    """A reply line that is not the answer expected: never parsed as data.

    Parameters
    ----------
    kind : str
        ``truncated`` (no line end: cut short or timed out), ``garbled`` (not ASCII,
        wrong field count, a field that is not a number), ``order`` (the reply of another
        command: a late answer) or ``refused`` (the robot did not know the command).
    detail : str
        What is wrong, for the message.
    line : bytes
        The bytes as received, for the log.
    """

    def __init__(self, kind: str, detail: str, line: bytes):
        super().__init__(f"{kind}: {detail} (bytes {line!r})")
        self.kind, self.detail, self.line = kind, detail, line


def command(letter: str, *values: int, dialect: str = "khepera2") -> bytes:
    """The bytes of one command: ``command("D", 10, -10)`` → ``b"D,10,-10\\r"``.

    Parameters
    ----------
    letter : str
        The command's letter (either case).
    *values : int
        Its arguments; a Khepera III's go out with their type prefix (``l20000``).
    dialect : str
        ``khepera2`` or ``khepera3``.

    Raises
    ------
    ValueError
        An unknown dialect.
    """
    if dialect not in DIALECTS:
        raise ValueError(f"dialect must be one of {DIALECTS}, got {dialect!r}")
    prefix = "l" if dialect == "khepera3" else ""
    fields = [letter.upper(), *(f"{prefix}{int(v)}" for v in values)]
    return (",".join(fields) + "\r").encode("ascii")


@dataclass(frozen=True)
class Reply:
    """One checked reply: its command's letter and its fields (ints; ``B``: strings)."""

    letter: str
    fields: tuple


def parse_reply(letter: str, line: bytes, *, dialect: str = "khepera2") -> Reply:
    """Check that ``line`` is the complete reply to command ``letter`` and parse it.

    Parameters
    ----------
    letter : str
        The command sent (either case).
    line : bytes
        The line received, with its ``\\r\\n``.
    dialect : str
        ``khepera2`` or ``khepera3``: how many fields each reply has.

    Raises
    ------
    ReplyError
        The line is truncated, garbled, another command's reply or an unknown-command line.
    """
    letter = letter.upper()
    if line == UNKNOWN_COMMAND_REPLY or (line and line.strip() == b""):
        raise ReplyError("refused", f"the robot does not know command {letter}", line)
    if not line.endswith(b"\r\n"):
        raise ReplyError("truncated", "no line end", line)
    try:
        text = line[:-2].decode("ascii")
    except UnicodeDecodeError:
        raise ReplyError("garbled", "not ASCII", line) from None
    if not text.isprintable():
        raise ReplyError("garbled", "control characters", line)
    head, *fields = text.split(",")
    if len(head) != 1 or not head.isalpha():
        raise ReplyError("garbled", f"no reply letter in {head!r}", line)
    if head != letter.lower():
        kind = "order" if head.islower() else "garbled"
        raise ReplyError(kind, f"a {head!r} reply while waiting for {letter.lower()!r}", line)
    expected = REPLY_FIELDS[dialect].get(letter)
    if expected is not None and len(fields) != expected:
        raise ReplyError("garbled", f"{len(fields)} fields, {letter} has {expected}", line)
    if letter == "B":
        return Reply(letter, tuple(fields))
    try:
        values = tuple(int(f) for f in fields)
    except ValueError:
        raise ReplyError("garbled", "a field that is not an integer", line) from None
    return Reply(letter, values)


def reply_line(letter: str, *values) -> bytes:
    """The bytes a robot answers command ``letter`` with (the emulator's side).

    Parameters
    ----------
    letter : str
        The command answered; the reply starts with it in lower case.
    *values : int or str
        The reply's fields, written with ``str``.
    """
    return (",".join([letter.lower(), *(str(v) for v in values)]) + "\r\n").encode("ascii")


def parse_command(line: bytes) -> tuple[str, tuple[int, ...]]:
    """A received command line (without its end) → its letter and integer arguments.

    Accepts both dialects (a ``l`` prefix on an argument is dropped).

    Raises
    ------
    ValueError
        Not a command of this protocol.
    """
    text = line.decode("ascii").strip()
    head, *args = text.split(",")
    if len(head) != 1 or not head.isalpha():
        raise ValueError(f"not a command: {text!r}")
    values = tuple(int(a[1:] if a[:1].isalpha() else a) for a in args)
    return head.upper(), values
