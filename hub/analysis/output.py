"""Writing outputs whole or not at all: a file written beside its place and moved there.

A full disk, a quota or a kill in the middle of a write leaves the file as it was (or no
file), never half of one: a reader -- a script gathering ``metrics.json`` over runs, a
browser opening a figure -- sees either the old file or the new one.
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path


def write_whole(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` whole: into a temporary file beside it, then moved there.

    Parameters
    ----------
    path : str or Path
        The file to write (replaced if there).
    data : bytes or str
        Its contents (a str is written as UTF-8).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OSError
        The write failed (a full disk, a read-only folder): ``path`` is as it was, and no
        temporary file is left.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    return path


def save_figure(fig, path: str | Path, **savefig: object) -> Path:
    """Save a matplotlib figure to ``path`` whole (:func:`write_whole`).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        Its format follows the suffix unless ``format`` is given.
    **savefig
        Passed to ``Figure.savefig`` (``dpi``, ``format``, ``bbox_inches``).
    """
    path = Path(path)
    buffer = io.BytesIO()
    savefig.setdefault("format", path.suffix.lstrip(".").lower() or None)
    fig.savefig(buffer, **savefig)
    return write_whole(path, buffer.getvalue())
