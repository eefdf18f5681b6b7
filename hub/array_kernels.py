"""Compiled checks of a message's larger arrays (``protocol.py``, ``replies.py``).

Above ``protocol.SMALL_ARRAY`` values, a check in numpy takes two or three calls of about
a microsecond each; one compiled pass takes a third of one. The kernels take arrays of
any flags and layout; they are compiled (or loaded from numba's cache) when this module
is imported, which the hub and each endpoint do before a run. Imported on first use
(:func:`hub.protocol.kernels`): a command that never checks a large array does not import
numba.
"""

from __future__ import annotations

from numba import njit, types


def any_array(dtype):
    """A 1-D array of ``dtype`` as numba types it, whatever its flags and layout: an
    array of any kind is taken by a kernel compiled for this."""
    return types.Array(dtype, 1, "A", readonly=True, aligned=False)


_BOUNDS = (types.float64, types.float64)
_BOUNDED = (types.float32, types.float64, types.uint32, types.uint8)  # the schemas' dtypes


@njit([(any_array(dtype), *_BOUNDS) for dtype in _BOUNDED], cache=True)
def within(arr, lo, hi):
    """True if every value is in ``[lo, hi]`` (so for floats none is NaN; with finite
    bounds none is infinite).

    Parameters
    ----------
    arr : 1-D array
        Of one of the schemas' dtypes (float32, float64, uint32, uint8).
    lo, hi : float
        The inclusive bounds.
    """
    for i in range(arr.size):
        if not (lo <= arr[i] <= hi):
            return False
    return True


@njit([(any_array(types.float32),), (any_array(types.float64),)], cache=True)
def ascending(arr):
    """True if the values never decrease."""
    for i in range(1, arr.size):
        if arr[i] < arr[i - 1]:
            return False
    return True


@njit([(any_array(types.uint32), any_array(types.boolean))], cache=True)
def all_known(channel, known):
    """True if every channel indexes a True of ``known``.

    Parameters
    ----------
    channel : 1-D uint32 array
        Channel numbers.
    known : 1-D bool array
        A table by channel number; a channel past its end is unknown.
    """
    for i in range(channel.size):
        c = channel[i]
        if c >= known.size or not known[c]:
            return False
    return True
