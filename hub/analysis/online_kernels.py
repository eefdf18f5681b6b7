"""Compiled per-spike work of the online burst detector (``online.py``).

Per channel, the spikes whose core status may still change wait in a ring buffer
(``q_t``, ``q_core``, from ``q_head``, ``q_len`` long); a spike leaves it, in time
order, once the watermark is more than ``window_ms`` past it, and then extends, opens
or closes its channel's open burst (``open_*``). The rules are those of the module
docstring of ``online.py``. The kernels release the interpreter (``nogil``): the hub's
threads that carry the loop's messages run while a burst is being analysed.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True)
def add_spikes(ch, t, q_t, q_core, q_head, q_len, min_spikes, window_ms):
    """Queue spikes (sorted by time) on their channels, marking every spike of a run of
    ``min_spikes`` spanning ``<= window_ms`` as core. Returns how many were queued: fewer
    than all when a channel's buffer is full (grow it and queue the rest).

    Parameters
    ----------
    ch : int array[k]
        Each spike's channel.
    t : float64[k]
        Each spike's time (ms), ascending.
    q_t, q_core : float64[n_channels, cap], bool[n_channels, cap]
        The ring buffers of queued spikes' times and core marks (updated in place).
    q_head, q_len : int64[n_channels]
        Each buffer's first slot and length (updated in place).
    min_spikes : int
        Spikes of a core run.
    window_ms : float
        The longest span of a core run.
    """
    cap = q_t.shape[1]
    for i in range(ch.size):
        c = ch[i]
        n = q_len[c]
        if n == cap:
            return i
        q_t[c, (q_head[c] + n) % cap] = t[i]
        q_core[c, (q_head[c] + n) % cap] = False
        n += 1
        q_len[c] = n
        if n >= min_spikes:
            first = (q_head[c] + n - min_spikes) % cap
            if t[i] - q_t[c, first] <= window_ms:
                for j in range(min_spikes):
                    q_core[c, (first + j) % cap] = True
    return ch.size


@njit(cache=True, nogil=True, inline="always")
def _close(c, open_start, open_last, open_n, min_spikes, nb, out):
    """End channel ``c``'s open burst (if any): a row of ``out`` if it has ``min_spikes``."""
    if open_n[c] >= min_spikes:
        out[nb, 0] = c
        out[nb, 1] = open_start[c]
        out[nb, 2] = open_last[c]
        out[nb, 3] = open_n[c]
        nb += 1
    open_n[c] = 0
    return nb


@njit(cache=True, nogil=True)
def advance_bursts(
    w_ms,
    q_t,
    q_core,
    q_head,
    q_len,
    open_start,
    open_last,
    open_n,
    min_spikes,
    window_ms,
    isi_ms,
    out,
):
    """Move the watermark to ``w_ms``: spikes more than ``window_ms`` behind it are final
    and join or end their channel's burst; a burst with no spike for ``isi_ms`` ends.
    Completed bursts (at least ``min_spikes`` spikes) go to the rows of ``out`` (channel,
    start, end, spike count; room for every queued spike plus one per channel).
    ``open_n[c] == 0``: no open burst on ``c``.

    Parameters
    ----------
    w_ms : float
        The new watermark: no spike before it is still to come.
    q_t, q_core, q_head, q_len
        The queues, as for :func:`add_spikes` (updated in place).
    open_start, open_last : float64[n_channels]
        Each channel's open burst: its first and last spike time (updated in place).
    open_n : int64[n_channels]
        Its spike count (updated in place).
    min_spikes : int
        The fewest spikes of a burst.
    window_ms : float
        How far behind the watermark a spike is final.
    isi_ms : float
        The longest interval within a burst.
    out : float64[rows, 4]
        Where completed bursts are written, from row 0.

    Returns
    -------
    n : int
        The number of bursts completed (rows of ``out`` written).
    safe_ms : float
        The time before which every burst start is known (the earliest open burst start
        or queued spike, else ``w_ms``).
    """
    cap = q_t.shape[1]
    safe = w_ms
    nb = 0
    for c in range(q_t.shape[0]):
        h = q_head[c]
        n = q_len[c]
        while n and w_ms - q_t[c, h] > window_ms:
            t = q_t[c, h]
            core = q_core[c, h]
            h = (h + 1) % cap
            n -= 1
            if core and open_n[c] and t - open_last[c] <= isi_ms:
                open_last[c] = t
                open_n[c] += 1
                continue
            nb = _close(c, open_start, open_last, open_n, min_spikes, nb, out)
            if core:
                open_start[c] = t
                open_last[c] = t
                open_n[c] = 1
        q_head[c] = h
        q_len[c] = n
        if open_n[c] and w_ms - open_last[c] > isi_ms:
            if n == 0 or q_t[c, h] - open_last[c] > isi_ms:
                nb = _close(c, open_start, open_last, open_n, min_spikes, nb, out)
        if open_n[c]:
            safe = min(safe, open_start[c])
        if n:
            safe = min(safe, q_t[c, h])
    return nb, safe
