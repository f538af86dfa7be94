"""Plain decimal numbers parsed vectorised, bit for bit what np.loadtxt returns: a day-long
1 s run has millions of cells, and numpy's C parser converting each on its own is ~4x slower."""

from __future__ import annotations

import numpy as np

_POW10 = 10.0 ** np.arange(16)
_PLAIN_DIGITS = 15  # up to 15 digits a decimal's integer is exact, and so is its quotient
_CHUNK_BYTES = 1 << 18  # rows parsed together: their per-character arrays stay in cache


def plain_numbers(text: str, start: int, sep: str, n_cols: int, n_rows: int | None = None
                   ) -> np.ndarray | None:
    """The rows of ``text`` from character ``start`` on (one a line; ``n_rows`` of them if
    given) as numbers, vectorised: what np.loadtxt reads from them,
    bit for bit, or None (then np.loadtxt, whose C parser converts every cell on its own,
    ~4x this). Each cell of at most 15 digits, a sign and a point is its digits' integer
    (exact below 2**53) divided by a power of ten (exact): one correctly rounded division,
    the same double as the decimal's correct rounding that the C parser returns. A cell with
    an exponent goes through float(); anything else (a blank, a letter, more digits, a
    short row) returns None."""
    try:
        raw = text.encode("ascii")  # ASCII: a character's index is its byte's
    except UnicodeEncodeError:
        return None
    if not raw.endswith(b"\n"):
        raw += b"\n"
    if start >= len(raw):
        return None
    ends = np.flatnonzero(np.frombuffer(raw, dtype=np.uint8, offset=start) == 10) + start
    if n_rows is None:
        n_rows = ends.size
    if ends.size != n_rows or not n_rows or len(sep) != 1 or n_cols < 1:
        return None
    out = np.empty((n_rows, n_cols))
    flat = out.reshape(-1)
    step = max(1, _CHUNK_BYTES * n_rows // (len(raw) - start))
    for r0 in range(0, n_rows, step):
        r1 = min(n_rows, r0 + step)
        a, b = (start if r0 == 0 else int(ends[r0 - 1]) + 1), int(ends[r1 - 1]) + 1
        cells = _plain_cells(raw[a:b], ord(sep), n_cols, r1 - r0)
        if cells is None:
            return None
        flat[r0 * n_cols:r1 * n_cols] = cells
    return out


def _plain_cells(raw: bytes, sep: int, n_cols: int, n_rows: int) -> np.ndarray | None:
    """The cells of ``raw`` (whole lines, each ending in a newline); see plain_numbers."""
    c = np.frombuffer(raw, dtype=np.uint8)
    is_sep = (c == sep) | (c == 10)
    ends = np.flatnonzero(is_sep)
    if ends.size != n_rows * n_cols or not (c[ends[n_cols - 1::n_cols]] == 10).all():
        return None  # a row of another length
    digit = c - np.uint8(48)
    is_digit = digit < 10
    dots = np.flatnonzero(c == 46)
    minus = np.flatnonzero(c == 45)
    other = np.flatnonzero((c == 101) | (c == 69) | (c == 43))  # e E +: float() reads them
    if (int(np.count_nonzero(is_digit)) + ends.size + dots.size + minus.size + other.size
            != c.size):
        return None  # another character: a blank, a letter, a quote
    cell_of = np.cumsum(is_sep, dtype=np.int64)
    cell_of -= is_sep
    seen = np.cumsum(is_digit, dtype=np.int64)
    upto = seen[ends]  # digits up to each cell's end
    count = np.diff(upto, prepend=0)
    special = np.zeros(ends.size, dtype=bool)
    special[cell_of[other]] = True
    if other.size:
        dots = dots[~special[cell_of[dots]]]
        minus = minus[~special[cell_of[minus]]]
    starts = np.empty_like(ends)
    starts[0] = 0
    starts[1:] = ends[:-1] + 1
    if minus.size and not (starts[cell_of[minus]] == minus).all():
        return None  # a sign inside a number
    plain = count[~special] if other.size else count
    if plain.size and (plain.min() < 1 or plain.max() > _PLAIN_DIGITS):
        return None  # an empty cell, a lone sign or point, or too many digits
    pos = np.flatnonzero(is_digit)
    cells = cell_of[pos]
    if other.size:
        keep = ~special[cells]
        pos, cells = pos[keep], cells[keep]
    # a cell's integer: its digits times 10 ** (digits after each); the sums are exact
    mant = np.bincount(cells, weights=digit[pos] * _POW10[upto[cells] - seen[pos]],
                       minlength=ends.size)
    scale = np.ones(ends.size)
    if dots.size:
        dot_cells = cell_of[dots]
        if (np.diff(dot_cells) == 0).any():
            return None  # two points in a cell
        scale[dot_cells] = _POW10[upto[dot_cells] - seen[dots]]
    values = mant / scale
    if minus.size:
        values[cell_of[minus]] *= -1.0
    for i in np.flatnonzero(special).tolist():
        try:
            values[i] = float(raw[starts[i]:ends[i]])
        except ValueError:
            return None
    return values
