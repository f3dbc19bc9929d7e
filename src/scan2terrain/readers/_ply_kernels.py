"""Compiled walks over the rows of a PLY element whose rows vary in length (list properties),
for :mod:`scan2terrain.readers.ply`: each row's place depends on the counts of the rows before
it, so the loop is the algorithm.

Each walk takes one element's properties as arrays, one entry a property: ``sizes`` (bytes of a
value), ``count_sizes`` (bytes of a list's count; 0 for a single value) and ``count_signed``.
It returns ``(status, row, prop, pos, count)``: :data:`FITS` when every row fits (``pos`` is
then where the element ends), else why the walk stopped, in which row and property, at which
byte, and the list's count where it has one.
"""

from __future__ import annotations

from scan2terrain._numba import numba as nb

#: How a walk ended.
FITS = 0
TRUNCATED = 1  # the data ends inside a row
NEGATIVE = 2  # a list count below 0
PAST_END = 3  # a list holding more values than the data has
NOT_AN_INTEGER = 4  # an ASCII list count that is not an integer
OUT_OF_RANGE = 5  # an ASCII list count beyond its type


@nb.njit(nogil=True, cache=True)
def walk_binary(data, pos, rows, sizes, count_sizes, count_signed, big):  # type: ignore[no-untyped-def]
    """Walk ``rows`` binary rows from byte ``pos`` of ``data`` (uint8)."""
    n = data.shape[0]
    for r in range(rows):
        for k in range(sizes.shape[0]):
            cs = count_sizes[k]
            if cs == 0:
                if pos + sizes[k] > n:
                    return TRUNCATED, r, k, pos, 0
                pos += sizes[k]
                continue
            if pos + cs > n:
                return TRUNCATED, r, k, pos, 0
            c = 0
            for i in range(cs):
                byte = data[pos + (cs - 1 - i if big else i)]
                c |= int(byte) << (8 * i)
            if count_signed[k] and c >= 1 << (8 * cs - 1):
                c -= 1 << (8 * cs)
            if c < 0:
                return NEGATIVE, r, k, pos, c
            if pos + cs + c * sizes[k] > n:
                return PAST_END, r, k, pos, c
            pos += cs + c * sizes[k]
    return FITS, -1, -1, pos, 0


@nb.njit(nogil=True, cache=True)
def _space(byte):  # type: ignore[no-untyped-def]
    """White space between the words of ASCII PLY data, as RPly has it: space, tab, CR, LF."""
    return byte == 32 or byte == 9 or byte == 10 or byte == 13  # noqa: PLR1714 (numba: no set)


@nb.njit(nogil=True, cache=True)
def _word_end(data, pos):  # type: ignore[no-untyped-def]
    n = data.shape[0]
    while pos < n and not _space(data[pos]):
        pos += 1
    return pos


@nb.njit(nogil=True, cache=True)
def skip_space(data, pos):  # type: ignore[no-untyped-def]
    """The first byte from ``pos`` that is not white space (the end of ``data`` if none)."""
    n = data.shape[0]
    while pos < n and _space(data[pos]):
        pos += 1
    return pos


@nb.njit(nogil=True, cache=True)
def walk_ascii(data, pos, rows, count_sizes, count_signed):  # type: ignore[no-untyped-def]
    """Walk ``rows`` ASCII rows (words apart, lines or not, as RPly reads them) from byte
    ``pos`` of ``data`` (uint8): each single value one word, each list an integer count of its
    type and as many words."""
    n = data.shape[0]
    for r in range(rows):
        for k in range(count_sizes.shape[0]):
            pos = skip_space(data, pos)
            if pos >= n:
                return TRUNCATED, r, k, pos, 0
            start, pos = pos, _word_end(data, pos)
            cs = count_sizes[k]
            if cs == 0:
                continue
            sign, i = 1, start
            if data[i] == 45 or data[i] == 43:  # '-', '+'
                sign = -1 if data[i] == 45 else 1
                i += 1
            if i == pos or pos - i > 12:
                return NOT_AN_INTEGER, r, k, start, 0
            c = 0
            for j in range(i, pos):
                digit = int(data[j]) - 48
                if digit < 0 or digit > 9:
                    return NOT_AN_INTEGER, r, k, start, 0
                c = 10 * c + digit
            c *= sign
            bits = 8 * cs - (1 if count_signed[k] else 0)
            if (c < 0 and not count_signed[k]) or c >= 1 << bits or c < -(1 << bits):
                return OUT_OF_RANGE, r, k, start, c
            if c < 0:
                return NEGATIVE, r, k, start, c
            for _ in range(c):
                pos = skip_space(data, pos)
                if pos >= n:
                    return PAST_END, r, k, start, c
                pos = _word_end(data, pos)
    return FITS, -1, -1, pos, 0
