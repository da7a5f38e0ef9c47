"""The Hilbert curve index of grid points, in any number of dimensions (paper Section VI).

The motion model reduces a flattened trajectory to a few principal components, scales them to
a grid of ``2**order`` levels per dimension (the paper: two components, order 5, levels 0..31)
and reduces the grid point to one number, its index along a Hilbert curve, so that clustering
becomes one-dimensional sorting.

The index is computed with J. Skilling's "transpose" algorithm (Programming the Hilbert curve,
AIP Conf. Proc. 707, 2004): ``AxesToTranspose`` turns the ``n`` coordinates into the
"transposed" index, whose bits interleaved (the bit-interleaving method the paper cites) give
the index. The numbering is exactly that of the ``hilbertcurve`` package
(``HilbertCurve(order, n_dims).distance_from_point``): at each level, from the most
significant bit down, the bit of coordinate 0 is the most significant of the ``n`` bits.

Everything is vectorised over points with numpy bit operations; Python loops run over the
order and the dimensions only. Grids of at most ``2**16`` cells (the paper's 32 x 32 among
them) are served from a lookup table built once per ``(n_dims, order)``.

Keys
----
A key has ``n_dims * order`` bits.

* ``n_dims * order <= 64``: keys are a ``uint64`` array, shape (n_points,).
* wider: keys are an ``object`` array of Python ints, shape (n_points,). They are exact, and
  compare, sort (``np.sort``, ``np.argsort``, ``sorted``) and subtract (``np.diff``) like the
  numbers they are, at the speed of Python ints.

:func:`sort_keys` (a stable argsort) and :func:`key_to_int` (a list of Python ints) work on
both forms.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.errors import InputError

__all__ = [
    "LUT_MAX_BITS",
    "MAX_ORDER",
    "decode",
    "encode",
    "encode_words",
    "grid_dtype",
    "key_bits",
    "key_to_int",
    "lookup_table",
    "quantize",
    "sort_keys",
]

#: Largest order: a coordinate must fit in a ``uint64``.
MAX_ORDER = 64

#: Grids of at most ``2**LUT_MAX_BITS`` cells are encoded and decoded by table look-up.
LUT_MAX_BITS = 16

_WORD = 64
_MASK64 = (1 << _WORD) - 1

Keys = NDArray[np.uint64] | NDArray[np.object_]
UIntArray = NDArray[np.unsignedinteger]


# --------------------------------------------------------------------------- validation


def _check_int(value: object, name: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name} must be an integer, got {value!r} ({type(value).__name__})")
    v = int(value)
    if v < low or (high is not None and v > high):
        span = f"in {low}..{high}" if high is not None else f">= {low}"
        raise InputError(f"{name} must be {span}, got {v}")
    return v


def _check_order(order: object) -> int:
    return _check_int(order, "order (bits per coordinate)", 1, MAX_ORDER)


def _check_n_dims(n_dims: object) -> int:
    return _check_int(n_dims, "n_dims", 1)


def key_bits(n_dims: int, order: int) -> int:
    """Number of bits of a key: ``n_dims * order``.

    Keys with at most 64 bits are ``uint64``; wider keys are Python ints.
    """
    return _check_n_dims(n_dims) * _check_order(order)


def grid_dtype(order: int) -> np.dtype[np.signedinteger | np.unsignedinteger]:
    """The dtype of grid coordinates returned by :func:`decode` and :func:`quantize`.

    ``int64`` (so that differences of coordinates do not wrap around), except ``uint64`` for
    ``order == 64``, whose largest coordinate ``2**64 - 1`` does not fit an ``int64``.
    """
    return np.dtype(np.uint64 if _check_order(order) == 64 else np.int64)


def _work_dtype(order: int) -> np.dtype[np.unsignedinteger]:
    # the narrowest unsigned type that holds a coordinate: less memory traffic per bit op
    for dt in (np.uint8, np.uint16, np.uint32):
        if order <= 8 * np.dtype(dt).itemsize:
            return np.dtype(dt)
    return np.dtype(np.uint64)


def _first(mask: NDArray[np.bool_]) -> tuple[int, ...]:
    """Index of the first True entry of ``mask`` (which has one)."""
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _py(value: object) -> object:
    """A numpy scalar as the Python number it holds, for messages (``5``, not ``np.int64(5)``)."""
    return value.item() if isinstance(value, np.generic) else value


def _object_ints(arr: NDArray[Any], name: str) -> NDArray[np.object_]:
    """The elements of an object array as Python ints (same shape); raise if one is not."""
    items = arr.ravel().tolist()
    # one C-level pass over the types; the per-element checks below only run on the odd
    # array that holds numpy integers (or culprits)
    if not set(map(type, items)) <= {int}:
        for j, v in enumerate(items):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                at = tuple(int(a) for a in np.unravel_index(j, arr.shape))
                raise InputError(
                    f"{name} must be integers, got {v!r} at index {at}; pass an integer array"
                )
        # numpy integers shift like C integers (a uint64 shifted by 64 is undefined);
        # Python ints shift exactly
        items = [int(v) for v in items]
    out = np.empty(len(items), dtype=object)
    out[:] = items
    return out.reshape(arr.shape)


def _object_to_uint64(arr: NDArray[Any], name: str, limit: int) -> NDArray[np.uint64]:
    """Check that an object array holds ints in ``[0, limit)`` with ``limit <= 2**64``."""
    ints = _object_ints(arr, name)
    if ints.size:
        _check_range(ints, name, limit)
    # every value is an int in [0, 2**64): the conversion is exact
    return ints.astype(np.uint64)


def _check_range(arr: NDArray[Any], name: str, limit: int) -> None:
    """Raise unless ``0 <= arr < limit`` (``arr`` non-empty, integer-valued)."""
    # compare as Python ints where numpy could not: uint64 against 2**64, object arrays
    low = arr.min()
    if low < 0:
        at = _first(arr < 0)
        raise InputError(f"{name} must be >= 0, got {_py(arr[at])!r} at index {at}")
    high = arr.max()
    if int(high) >= limit:
        at = _first(arr == high)
        raise InputError(
            f"{name} must be < {limit}, got {_py(arr[at])!r} at index {at}; "
            "raise the order or quantize the data to the grid first"
        )


def _as_uint(arr: NDArray[Any], name: str, limit: int) -> NDArray[np.uint64]:
    """Check integer values in ``[0, limit)`` (``limit <= 2**64``); return them as uint64.

    ``arr`` may be of integer, float (integral values only) or object (Python ints) dtype.
    """
    kind = arr.dtype.kind
    if kind == "O":
        return _object_to_uint64(arr, name, limit)
    if kind == "b":
        raise InputError(
            f"{name} must be integers, got a boolean array; cast it with .astype(int) "
            "if 0/1 values are meant"
        )
    if kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            at = _first(bad)
            raise InputError(f"{name} must be finite integers, got {_py(arr[at])!r} at index {at}")
        frac = arr != np.floor(arr)
        if frac.any():
            at = _first(frac)
            raise InputError(
                f"{name} must be integers, got {_py(arr[at])!r} at index {at}; "
                "round or quantize the values (see quantize) first"
            )
        if arr.size and float(arr.max()) >= 2.0**53 and limit > 2**53:
            # above 2**53 a float64 no longer holds every integer: the value may not be the
            # one the caller meant
            raise InputError(
                f"{name} hold floats >= 2**53, which are not exact integers; "
                "pass an integer array (uint64) or Python ints"
            )
    elif kind not in "iu":
        raise InputError(f"{name} must be an integer array, got dtype {arr.dtype}")
    if arr.size:
        _check_range(arr, name, limit)
    return arr.astype(np.uint64)


def _read(obj: ArrayLike, what: str) -> NDArray[Any]:
    """``np.asarray(obj)``, keeping Python ints exact and wrapping numpy's errors."""
    try:
        arr = np.asarray(obj)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{what}; could not read them as an array ({exc})") from None
    if arr.dtype.kind == "f" and not isinstance(obj, np.ndarray):
        # numpy reads a list mixing ints below 2**63 and ints in [2**63, 2**64) as floats,
        # which would lose the low bits: keep Python ints as they are
        as_obj = np.array(obj, dtype=object)
        if as_obj.shape == arr.shape and set(map(type, as_obj.ravel().tolist())) <= {int}:
            return as_obj
    return arr


def _as_points(points: ArrayLike, order: int) -> NDArray[np.uint64]:
    arr = _read(
        points, "points must be an array of integer grid coordinates, shape (n_points, n_dims)"
    )
    if arr.ndim != 2 or arr.shape[1] == 0:
        raise InputError(
            "points must have shape (n_points, n_dims) with n_dims >= 1, got shape "
            f"{arr.shape}; use .reshape(1, -1) for one point or .reshape(-1, 1) for 1-D points"
        )
    return _as_uint(arr, f"grid coordinates (order {order}: 0..{2**order - 1})", 1 << order)


def _as_keys(keys: ArrayLike, n_bits: int) -> NDArray[np.uint64] | NDArray[np.object_]:
    arr = _read(keys, "keys must be a 1-D array of Hilbert indices")
    if arr.ndim != 1:
        raise InputError(
            f"keys must have shape (n_keys,), got shape {arr.shape}; flatten them with .ravel()"
        )
    name = f"Hilbert keys ({n_bits} bits: 0..2**{n_bits} - 1)"
    if n_bits <= _WORD or arr.dtype.kind != "O":
        return _as_uint(arr, name, 1 << min(n_bits, _WORD))
    ints = _object_ints(arr, name)
    if ints.size:
        _check_range(ints, name, 1 << n_bits)
    return ints


# --------------------------------------------------------------------------- Skilling


class _Scratch:
    """Work arrays shared by the steps of one transform, to spare allocations."""

    def __init__(self, like: UIntArray) -> None:
        self.hit = np.empty_like(like)
        self.low = np.empty_like(like)
        self.tmp = np.empty_like(like)


def _excess_step(x: list[UIntArray], i: int, k: int, s: _Scratch) -> None:
    """One step of Skilling's excess-work loop at level ``q = 2**k``, in place.

    Per point: if bit ``k`` of ``X[i]`` is set, invert the low ``k`` bits of ``X[0]``;
    otherwise exchange the low ``k`` bits of ``X[0]`` and ``X[i]``. The branch is taken per
    point with an all-ones/all-zeros mask rather than ``np.where``: plain bit ufuncs written
    into preallocated arrays ran about 14 times faster here.
    """
    dt = x[0].dtype.type
    p = dt((1 << k) - 1)
    hit, low, tmp = s.hit, s.low, s.tmp
    np.right_shift(x[i], dt(k), out=hit)
    np.bitwise_and(hit, dt(1), out=hit)
    np.negative(hit, out=hit)  # 0 - 1 wraps to all ones: the "bit set" mask
    if i == 0:
        # exchanging X[0] with itself does nothing; only the inversion is left
        np.bitwise_and(hit, p, out=hit)
        x[0] ^= hit
        return
    np.bitwise_xor(x[0], x[i], out=low)
    np.bitwise_and(low, p, out=low)  # the low bits where X[0] and X[i] differ
    # X[0] ^= p where set, ^= low where not: low ^ ((p ^ low) & hit)
    np.bitwise_xor(low, p, out=tmp)
    np.bitwise_and(tmp, hit, out=tmp)
    np.bitwise_xor(tmp, low, out=tmp)
    x[0] ^= tmp
    np.invert(hit, out=hit)
    np.bitwise_and(low, hit, out=low)
    x[i] ^= low


def _axes_to_transpose(x: list[UIntArray], order: int) -> None:
    """Skilling's ``AxesToTranspose``, in place, vectorised over points.

    Parameters
    ----------
    x : list of n arrays, each shape (n_points,)
        Coordinates ``X[i]`` of the points on entry; the transposed Hilbert index on exit.
    order : int
        Bits per coordinate.
    """
    n = len(x)
    dt = x[0].dtype.type
    s = _Scratch(x[0])
    # inverse undo of the excess work, from the top level down
    for k in range(order - 1, 0, -1):
        for i in range(n):
            _excess_step(x, i, k, s)
    # Gray encode
    for i in range(1, n):
        x[i] ^= x[i - 1]
    t = np.zeros_like(x[0])
    for k in range(order - 1, 0, -1):
        # t ^= q - 1 where bit k of X[n-1] is set
        np.right_shift(x[n - 1], dt(k), out=s.hit)
        np.bitwise_and(s.hit, dt(1), out=s.hit)
        np.negative(s.hit, out=s.hit)
        np.bitwise_and(s.hit, dt((1 << k) - 1), out=s.hit)
        t ^= s.hit
    for i in range(n):
        x[i] ^= t


def _transpose_to_axes(x: list[UIntArray], order: int) -> None:
    """Skilling's ``TransposetoAxes``, in place, vectorised over points (inverse of above)."""
    n = len(x)
    dt = x[0].dtype.type
    s = _Scratch(x[0])
    # Gray decode by H ^ (H / 2)
    t = x[n - 1] >> dt(1)
    for i in range(n - 1, 0, -1):
        x[i] ^= x[i - 1]
    x[0] ^= t
    # undo the excess work, from the bottom level up
    for k in range(1, order):
        for i in range(n - 1, -1, -1):
            _excess_step(x, i, k, s)


# --------------------------------------------------------------------------- bit interleaving


def _bit_moves(n: int, order: int) -> list[tuple[int, int, int, int]]:
    """Where each bit of the transposed index goes in the key.

    Returns ``(b, i, w, s)`` for every level ``b`` and dimension ``i``: bit ``b`` of ``X[i]``
    is bit ``s`` of key word ``w`` (words most significant first). Bit ``b`` of ``X[i]`` is
    bit ``b * n + (n - 1 - i)`` of the key: level-major, coordinate 0 most significant
    within a level, as ``hilbertcurve`` interleaves.
    """
    n_words = -(-n * order // _WORD)
    moves = []
    for b in range(order):
        for i in range(n):
            pos = b * n + (n - 1 - i)
            moves.append((b, i, n_words - 1 - pos // _WORD, pos % _WORD))
    return moves


def _shift_into(src: NDArray[np.uint64], frm: int, to: int, out: NDArray[np.uint64]) -> None:
    """``out = bit frm of src, moved to bit to`` (other bits zero)."""
    if to >= frm:
        np.left_shift(src, np.uint64(to - frm), out=out)
    else:
        np.right_shift(src, np.uint64(frm - to), out=out)
    np.bitwise_and(out, np.uint64(1 << to), out=out)


def _spread2(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Bit ``b`` of ``v`` (< 2**32) moved to bit ``2 b`` (the classic "part 1 by 1")."""
    v = v & np.uint64(0x00000000FFFFFFFF)
    for shift, mask in ((16, 0x0000FFFF0000FFFF), (8, 0x00FF00FF00FF00FF),
                        (4, 0x0F0F0F0F0F0F0F0F), (2, 0x3333333333333333),
                        (1, 0x5555555555555555)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _spread3(v: NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Bit ``b`` of ``v`` (< 2**21) moved to bit ``3 b`` ("part 1 by 2")."""
    v = v & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF),
                        (8, 0x100F00F00F00F00F), (4, 0x10C30C30C30C30C3),
                        (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


_SPREAD = {2: _spread2, 3: _spread3}


def _interleave(x: list[UIntArray], order: int) -> list[NDArray[np.uint64]]:
    """Interleave the transposed index into 64-bit words, most significant word first.

    One shift, mask and or per bit of the key, over all points at once. (np.unpackbits /
    np.packbits with a transpose between them was tried: 2 to 5 times slower, from the
    strided byte copies.)

    Returns
    -------
    list of n_words arrays, each shape (n_points,)
        ``n_words = ceil(n * order / 64)``.
    """
    n = len(x)
    m = x[0].shape[0]
    if n in _SPREAD and n * order <= _WORD:
        # two or three coordinates in one word: spread each coordinate's bits by magic
        # numbers (a few shifts and masks for all bits at once), then shift them into place
        spread = _SPREAD[n]
        key = np.zeros(m, dtype=np.uint64)
        for i in range(n):
            key |= spread(x[i].astype(np.uint64)) << np.uint64(n - 1 - i)
        return [key]
    words = [np.zeros(m, dtype=np.uint64) for _ in range(-(-n * order // _WORD))]
    x64 = [a.astype(np.uint64) for a in x]
    tmp = np.empty(m, dtype=np.uint64)
    for b, i, w, s in _bit_moves(n, order):
        _shift_into(x64[i], b, s, tmp)
        words[w] |= tmp
    return words


def _deinterleave(words: list[NDArray[np.uint64]], n: int, order: int) -> list[UIntArray]:
    """Inverse of :func:`_interleave`: n_words arrays -> n coordinate arrays."""
    m = words[0].shape[0]
    x = [np.zeros(m, dtype=np.uint64) for _ in range(n)]
    tmp = np.empty(m, dtype=np.uint64)
    for b, i, w, s in _bit_moves(n, order):
        _shift_into(words[w], s, b, tmp)
        x[i] |= tmp
    dt = _work_dtype(order)
    return [a.astype(dt) for a in x]


def _words_to_keys(words: list[NDArray[np.uint64]]) -> Keys:
    if len(words) == 1:
        return words[0]
    key = words[0].astype(object)
    for w in words[1:]:
        key = (key << _WORD) | w.astype(object)
    return key


def _keys_to_words(
    keys: NDArray[np.uint64] | NDArray[np.object_], n_bits: int
) -> list[NDArray[np.uint64]]:
    n_words = -(-n_bits // _WORD)
    if keys.dtype != object:
        # integer keys are below 2**64: the low word, zeros above
        return [np.zeros(keys.shape[0], dtype=np.uint64) for _ in range(n_words - 1)] + [
            keys.astype(np.uint64)
        ]
    return [((keys >> (_WORD * k)) & _MASK64).astype(np.uint64) for k in range(n_words - 1, -1, -1)]


# --------------------------------------------------------------------------- scalar path

#: Points at most this many are encoded one by one on Python ints (a single registration):
#: the vectorised transform's numpy calls cost tens of microseconds each on tiny arrays.
SCALAR_MAX_POINTS = 4


def _encode_int(coords: list[int], order: int) -> int:
    """Skilling's transform and the bit interleaving of one point, on Python ints.

    The same steps as :func:`_axes_to_transpose` and :func:`_interleave`, with a branch per
    point instead of masks: about 15 microseconds for a 6-D order-10 key, where the
    vectorised path spends most of a millisecond on one-element arrays.
    """
    x = list(coords)
    n = len(x)
    q = 1 << (order - 1)
    while q > 1:
        p = q - 1
        for i in range(n):
            if x[i] & q:
                x[0] ^= p
            else:
                t = (x[0] ^ x[i]) & p
                x[0] ^= t
                x[i] ^= t
        q >>= 1
    for i in range(1, n):
        x[i] ^= x[i - 1]
    t = 0
    q = 1 << (order - 1)
    while q > 1:
        if x[n - 1] & q:
            t ^= q - 1
        q >>= 1
    key = 0
    for b in range(order - 1, -1, -1):
        for i in range(n):
            key = (key << 1) | (((x[i] ^ t) >> b) & 1)
    return key


# --------------------------------------------------------------------------- general path


def _encode_general(pts: NDArray[np.uint64], order: int) -> Keys:
    dt = _work_dtype(order)
    x = [np.ascontiguousarray(pts[:, i], dtype=dt) for i in range(pts.shape[1])]
    _axes_to_transpose(x, order)
    return _words_to_keys(_interleave(x, order))


def _decode_general(
    keys: NDArray[np.uint64] | NDArray[np.object_], n_dims: int, order: int
) -> NDArray[np.signedinteger | np.unsignedinteger]:
    x = _deinterleave(_keys_to_words(keys, n_dims * order), n_dims, order)
    _transpose_to_axes(x, order)
    out = np.empty((keys.shape[0], n_dims), dtype=grid_dtype(order))
    for i in range(n_dims):
        out[:, i] = x[i]
    return out


# --------------------------------------------------------------------------- lookup tables


@functools.cache
def _tables(
    n_dims: int, order: int
) -> tuple[NDArray[np.uint64], NDArray[np.signedinteger | np.unsignedinteger]]:
    """Encode and decode tables of a small grid (``n_dims * order <= LUT_MAX_BITS``).

    Returns
    -------
    enc : array, shape (2**(n_dims * order),)
        ``enc[c]``: key of the cell whose row-major number (coordinate 0 most significant)
        is ``c``.
    dec : array, shape (2**(n_dims * order), n_dims)
        ``dec[h]``: the cell of key ``h``.
    """
    # the cache holds at most a few dozen read-only tables (one per small (n_dims, order))
    size = 1 << (n_dims * order)
    cells = _row_major_cells(np.arange(size, dtype=np.uint64), n_dims, order)
    enc = _encode_general(cells, order)
    dec = _decode_general(np.arange(size, dtype=np.uint64), n_dims, order)
    enc.flags.writeable = False
    dec.flags.writeable = False
    return enc, dec  # type: ignore[return-value]


def lookup_table(n_dims: int, order: int) -> NDArray[np.uint64]:
    """The read-only encode table of a small grid (``n_dims * order <= LUT_MAX_BITS``).

    ``table[c]`` is the key of the cell whose row-major number (coordinate 0 most
    significant, ``order`` bits each) is ``c``: callers that quantize their own points (the
    clusterer's single-sample registration) skip :func:`encode`'s input checks with it.
    """
    n_dims = _check_n_dims(n_dims)
    order = _check_order(order)
    if n_dims * order > LUT_MAX_BITS:
        raise InputError(
            f"lookup tables hold grids of at most 2**{LUT_MAX_BITS} cells, got "
            f"n_dims * order = {n_dims * order} bits"
        )
    return _tables(n_dims, order)[0]


def _row_major_cells(c: NDArray[np.uint64], n_dims: int, order: int) -> NDArray[np.uint64]:
    mask = np.uint64((1 << order) - 1)
    return np.stack(
        [(c >> np.uint64(order * (n_dims - 1 - i))) & mask for i in range(n_dims)], axis=1
    )


def _row_major_index(pts: NDArray[np.uint64], order: int) -> NDArray[np.intp]:
    n_dims = pts.shape[1]
    # shift and or straight from each (strided) column into one intp array: no astype copy
    # of a column (two of them were half the cost of a 2-D order-5 encoding)
    c: NDArray[np.intp] = np.left_shift(pts[:, 0], order * (n_dims - 1), dtype=np.intp,
                                        casting="unsafe")
    tmp = np.empty_like(c) if n_dims > 2 else c
    for i in range(1, n_dims):
        col = pts[:, i]
        if i < n_dims - 1:
            col = np.left_shift(col, order * (n_dims - 1 - i), out=tmp, dtype=np.intp,
                                casting="unsafe")
        np.bitwise_or(c, col, out=c, dtype=np.intp, casting="unsafe")
    return c


def _gather(table: NDArray[np.uint64], cells: NDArray[np.intp]) -> NDArray[np.uint64]:
    """``table[cells]``, written over ``cells`` (both 8-byte words): one array allocated per
    encoding, not two (a fresh 8 MB array costs its page faults: with two, the encoding of
    10^6 points swung between 2.5 and 7 ms)."""
    out = cells.view(np.uint64)
    # elementwise, each index is read before its own slot is written; "clip" (indices are in
    # range) lets numpy write into out directly instead of through a buffer
    np.take(table, cells, out=out, mode="clip")
    return out


def _in_range(points: NDArray[np.integer], order: int) -> bool:
    """Whether every coordinate of an integer array is in ``[0, 2**order)``, in one pass.

    The bitwise or of all values, read as unsigned integers of the same width, is below
    ``2**order`` exactly when they all are (a negative value sets the top bit).
    """
    flat = np.ascontiguousarray(points).reshape(-1)
    if flat.dtype.kind == "i" and order >= 8 * flat.dtype.itemsize - 1 and flat.size:
        # the top bit a negative value sets is then inside [0, 2**order): ask the sign directly
        return bool(flat.min() >= 0)
    unsigned = flat.view(np.dtype(f"u{flat.dtype.itemsize}"))
    return int(np.bitwise_or.reduce(unsigned)) >> order == 0


# --------------------------------------------------------------------------- public API


def encode(points: ArrayLike, order: int, *, validate: bool = True) -> Keys:
    """Hilbert indices of grid points.

    Parameters
    ----------
    points : array_like of int, shape (n_points, n_dims)
        Grid coordinates, each in ``[0, 2**order)``: the paper's scaled principal
        components. Floats with integral values below ``2**53`` are accepted; coordinates
        of ``2**63`` or more (order 64) need a ``uint64`` array or Python ints.
    order : int
        Bits per coordinate, ``1..MAX_ORDER`` (the paper: 5, a 32-level grid).
    validate : bool
        ``False`` skips the input checks, for callers that made the grid themselves (the
        clusterer, after :func:`quantize`): the points must then be a non-negative integer
        array in range, or the keys are undefined.

    Returns
    -------
    keys : array, shape (n_points,)
        The index ``h`` of each point along the Hilbert curve, ``0 <= h < 2**(n_dims*order)``,
        equal to ``hilbertcurve``'s ``HilbertCurve(order, n_dims).distance_from_point``.
        ``uint64`` when ``n_dims * order <= 64``, else ``object`` (Python ints).

    Raises
    ------
    InputError
        If ``order`` is not an integer in ``1..MAX_ORDER``, or ``points`` is not 2-D, or a
        coordinate is not an integer in ``[0, 2**order)`` (NaN included); the message gives
        the index of the first culprit.
    """
    if validate:
        order = _check_order(order)
    if (isinstance(points, np.ndarray) and points.dtype.kind in "iu" and points.ndim == 2
            and points.shape[0] and 0 < points.shape[1] * order <= LUT_MAX_BITS
            and (not validate or _in_range(points, order))):
        # the table path on an integer array already in range: one pass for the bounds,
        # the row-major cell number, one gather (no copy to uint64)
        enc, _ = _tables(points.shape[1], order)
        return _gather(enc, _row_major_index(points, order))
    pts = _as_points(points, order) if validate else np.asarray(points, dtype=np.uint64)
    n_dims = pts.shape[1]
    if pts.shape[0] == 0:
        return np.zeros(0, dtype=np.uint64 if n_dims * order <= _WORD else object)
    if n_dims * order <= LUT_MAX_BITS:
        enc, _ = _tables(n_dims, order)
        return _gather(enc, _row_major_index(pts, order))
    if pts.shape[0] <= SCALAR_MAX_POINTS:
        ints = [_encode_int(row, order) for row in pts.tolist()]
        if n_dims * order <= _WORD:
            return np.array(ints, dtype=np.uint64)
        out = np.empty(len(ints), dtype=object)
        out[:] = ints
        return out
    return _encode_general(pts, order)


def encode_words(points: ArrayLike, order: int) -> NDArray[np.uint64]:
    """Hilbert indices as 64-bit words, most significant first: shape (n_points, n_words).

    ``n_words = ceil(n_dims * order / 64)``: one word up to 64 bits, two words for keys of
    65 to 128 bits, and so on. The words sort lexicographically like the keys (e.g.
    ``np.lexsort(words.T[::-1])``) and skip building Python ints, which costs most of the
    encoding of wide keys. Same arguments and checks as :func:`encode`.
    """
    order = _check_order(order)
    pts = _as_points(points, order)
    n_dims = pts.shape[1]
    n_words = -(-n_dims * order // _WORD)
    if pts.shape[0] == 0:
        return np.zeros((0, n_words), dtype=np.uint64)
    if n_dims * order <= _WORD:
        return np.asarray(encode(pts, order, validate=False), dtype=np.uint64)[:, None]
    dt = _work_dtype(order)
    x = [np.ascontiguousarray(pts[:, i], dtype=dt) for i in range(n_dims)]
    _axes_to_transpose(x, order)
    return np.stack(_interleave(x, order), axis=1)


def decode(
    keys: ArrayLike, n_dims: int, order: int
) -> NDArray[np.signedinteger | np.unsignedinteger]:
    """Grid points of Hilbert indices: the inverse of :func:`encode`.

    Parameters
    ----------
    keys : array_like of int, shape (n_keys,)
        Indices ``h``, ``0 <= h < 2**(n_dims*order)``: a ``uint64`` (or other integer) array,
        or Python ints (an ``object`` array or a list) for keys wider than 64 bits.
    n_dims : int
        Number of dimensions, ``>= 1``.
    order : int
        Bits per coordinate, ``1..MAX_ORDER``.

    Returns
    -------
    points : array, shape (n_keys, n_dims)
        Grid coordinates in ``[0, 2**order)``, dtype :func:`grid_dtype` (``int64``, or
        ``uint64`` for order 64), equal to ``hilbertcurve``'s ``point_from_distance``.

    Raises
    ------
    InputError
        If ``n_dims`` or ``order`` is invalid, ``keys`` is not 1-D, or a key is not an
        integer in range; the message gives the index of the first culprit.
    """
    n_dims = _check_n_dims(n_dims)
    order = _check_order(order)
    n_bits = n_dims * order
    arr = _as_keys(keys, n_bits)
    if arr.shape[0] == 0:
        return np.zeros((0, n_dims), dtype=grid_dtype(order))
    if n_bits <= LUT_MAX_BITS:
        _, dec = _tables(n_dims, order)
        return dec[arr.astype(np.intp)]
    return _decode_general(arr, n_dims, order)


def key_to_int(keys: ArrayLike) -> list[int]:
    """Keys as a list of Python ints, whatever their form (``uint64`` or ``object``).

    Raises
    ------
    InputError
        If ``keys`` is not 1-D or holds something other than non-negative integers.
    """
    arr = _keys_any_width(keys)
    return [int(k) for k in arr.tolist()]


def sort_keys(keys: ArrayLike) -> NDArray[np.intp]:
    """Indices that sort keys in increasing order (stable: ties keep their order).

    Works on both key forms; ``keys[sort_keys(keys)]`` is sorted.

    Returns
    -------
    order : array of intp, shape (n_keys,)

    Raises
    ------
    InputError
        If ``keys`` is not 1-D or holds something other than non-negative integers.
    """
    arr = _keys_any_width(keys)
    # numpy sorts object arrays with Python comparisons: exact for wide keys, and stable
    return np.argsort(arr, kind="stable")


def _keys_any_width(keys: ArrayLike) -> NDArray[np.uint64] | NDArray[np.object_]:
    arr = _read(keys, "keys must be a 1-D array of Hilbert indices")
    if arr.ndim != 1:
        raise InputError(f"keys must have shape (n_keys,), got shape {arr.shape}")
    if arr.dtype.kind == "O":
        ints = _object_ints(arr, "keys")
        if ints.size and ints.min() < 0:
            at = _first(ints < 0)
            raise InputError(f"keys must be >= 0, got {_py(ints[at])!r} at index {at}")
        return ints
    return _as_uint(arr, "keys", 1 << _WORD)


def quantize(
    X: ArrayLike, lower: ArrayLike, upper: ArrayLike, order: int
) -> tuple[NDArray[np.signedinteger | np.unsignedinteger], NDArray[np.bool_]]:
    """Scale continuous points to the grid of :func:`encode`.

    Each dimension's range ``[lower, upper]`` is cut into ``2**order`` cells of equal width;
    a value goes to the cell it falls in, ``upper`` itself to the last cell (the paper: two
    principal components scaled to 0..31 for order 5). Equal cells, rather than rounding
    ``(x - lower) / (upper - lower) * (2**order - 1)``, give the end levels the same share of
    the range as the others.

    Parameters
    ----------
    X : array_like of float, shape (n_samples, n_dims)
        The points (e.g. principal components of flattened trajectories).
    lower, upper : float or array_like, shape (n_dims,)
        Bounds of the grid per dimension, ``lower < upper``.
    order : int
        Bits per coordinate, ``1..MAX_ORDER``.

    Returns
    -------
    grid : array, shape (n_samples, n_dims)
        Cell coordinates in ``[0, 2**order)``, dtype :func:`grid_dtype`. A value outside its
        bounds is put in the nearest end cell, so that ``grid`` is always valid input to
        :func:`encode`; ``outside`` says which rows that happened to.
    outside : array of bool, shape (n_samples,)
        True where a coordinate of the row lies outside ``[lower, upper]``: the caller
        decides whether to drop the row, keep its end cell, or widen the bounds.

    Raises
    ------
    InputError
        If ``X`` is not a 2-D array of finite numbers, the bounds do not broadcast to
        ``(n_dims,)``, are not finite, or ``lower >= upper`` in some dimension.
    """
    order = _check_order(order)
    try:
        x = np.asarray(X, dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise InputError(
            f"X must be a numeric array, shape (n_samples, n_dims); could not read it ({exc})"
        ) from None
    if x.ndim != 2 or x.shape[1] == 0:
        raise InputError(
            f"X must have shape (n_samples, n_dims) with n_dims >= 1, got shape {x.shape}"
        )
    bad = ~np.isfinite(x)
    if bad.any():
        at = _first(bad)
        raise InputError(
            f"X must be finite, got {x[at]} at index {at}; drop or fill missing samples first"
        )
    n_dims = x.shape[1]
    lo = _bound(lower, "lower", n_dims)
    hi = _bound(upper, "upper", n_dims)
    empty = lo >= hi
    if empty.any():
        d = int(np.argmax(empty))
        raise InputError(
            f"lower must be < upper in every dimension, got lower={lo[d]}, upper={hi[d]} "
            f"in dimension {d}"
        )
    outside: NDArray[np.bool_] = np.any((x < lo) | (x > hi), axis=1)
    levels = 2.0**order
    u = (x - lo) / (hi - lo)
    # the largest double below 1 keeps upper (and beyond) inside the last cell
    cell = np.floor(np.clip(u, 0.0, math.nextafter(1.0, 0.0)) * levels)
    grid = cell.astype(grid_dtype(order))
    return grid, outside


def _bound(value: ArrayLike, name: str, n_dims: int) -> NDArray[np.float64]:
    try:
        b = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_dims,))
    except (ValueError, TypeError):
        raise InputError(
            f"{name} must be a number or an array of shape ({n_dims},), got {value!r}"
        ) from None
    if not np.isfinite(b).all():
        raise InputError(f"{name} must be finite, got {value!r}")
    return b
