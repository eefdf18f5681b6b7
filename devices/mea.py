"""The Multi Channel Systems 60-electrode MEA: an 8 x 8 grid without its four corners.

Electrodes are named by their column digit then their row digit, both counted from 1:
12-17, 21-28, ..., 71-78, 82-87 (11, 18, 81 and 88 are the missing corners). The pitch is
200 um (30 um electrodes) or 100 um (10 um electrodes).
"""

from __future__ import annotations

import numpy as np

#: rows and columns of the grid
MCS60_ROWS = 8
MCS60_COLS = 8
#: electrode pitch of the common layout (30 um electrodes)
MCS60_PITCH_UM = 200.0
#: the pitches MCS makes the layout in (30 um and 10 um electrodes)
MCS60_PITCHES_UM = (200.0, 100.0)
#: number of electrodes
MCS60_N = 60


def grid(rows: int, cols: int, drop_corners: bool) -> tuple[np.ndarray, np.ndarray]:
    """Row and column index of each electrode of a grid, row-major.

    Parameters
    ----------
    rows, cols : int
        Grid size (>= 1).
    drop_corners : bool
        Leave out the four corners (as MCS does), when the grid has more than one row and
        more than one column.

    Returns
    -------
    row, col : int64[n]
        Zero-based indices, row-major (row 0's electrodes first).
    """
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    r, c = r.ravel(), c.ravel()
    if drop_corners and rows > 1 and cols > 1:
        corner = ((r == 0) | (r == rows - 1)) & ((c == 0) | (c == cols - 1))
        r, c = r[~corner], c[~corner]
    return r, c


def positions(
    rows: int, cols: int, pitch_um: float, drop_corners: bool, centre_um=(0.0, 0.0)
) -> tuple[np.ndarray, np.ndarray]:
    """Electrode positions of a grid, row-major (as :func:`grid`), centred on ``centre_um``.

    Parameters
    ----------
    rows, cols : int
        Grid size (>= 1).
    pitch_um : float
        Distance between neighbouring electrodes, µm.
    drop_corners : bool
        As for :func:`grid`.
    centre_um : (float, float)
        Where the grid's centre is, µm.

    Returns
    -------
    x_um, y_um : float32[n]
        x from the column, y from the row (row 0 at the smallest y).
    """
    r, c = grid(rows, cols, drop_corners)
    x = centre_um[0] + (c - (cols - 1) / 2.0) * pitch_um
    y = centre_um[1] + (r - (rows - 1) / 2.0) * pitch_um
    return x.astype(np.float32), y.astype(np.float32)


def name(row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """MCS electrode names (column digit, row digit) of zero-based grid indices.

    Parameters
    ----------
    row, col : int array_like
        Zero-based indices in an 8 x 8 grid.

    Returns
    -------
    int64 array
        ``10 * (col + 1) + (row + 1)``, e.g. 12 for row 1, column 0.
    """
    return 10 * (np.asarray(col, dtype=np.int64) + 1) + (np.asarray(row, dtype=np.int64) + 1)


#: the 60 electrode names, in the row-major order of ``grid(8, 8, True)``
MCS60_NAMES = name(*grid(MCS60_ROWS, MCS60_COLS, drop_corners=True))
