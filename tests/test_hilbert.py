"""The Hilbert index: against the ``hilbertcurve`` package, the curve's own definition, and
hand-worked grids."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from nonprehensile.errors import InputError
from nonprehensile.motion.hilbert import (
    LUT_MAX_BITS,
    MAX_ORDER,
    SCALAR_MAX_POINTS,
    decode,
    encode,
    encode_words,
    grid_dtype,
    key_bits,
    key_to_int,
    quantize,
    sort_keys,
)

hc = pytest.importorskip("hilbertcurve.hilbertcurve")


@st.composite
def grids(draw: st.DrawFn) -> tuple[int, int, list[list[int]]]:
    """(n_dims, order, points): dims 1..10, orders 1..12, 1..20 points on the grid."""
    n_dims = draw(st.integers(1, 10))
    order = draw(st.integers(1, 12))
    coord = st.integers(0, 2**order - 1)
    pts = draw(st.lists(st.lists(coord, min_size=n_dims, max_size=n_dims), min_size=1, max_size=20))
    return n_dims, order, pts


@settings(max_examples=100)
@given(grids())
def test_encode_equals_hilbertcurve_and_round_trips(case: tuple[int, int, list[list[int]]]) -> None:
    n_dims, order, pts = case
    curve = hc.HilbertCurve(order, n_dims)
    keys = encode(np.array(pts, dtype=np.int64), order)
    assert key_to_int(keys) == [curve.distance_from_point(p) for p in pts]
    assert keys.dtype == (np.uint64 if n_dims * order <= 64 else object)
    back = decode(keys, n_dims, order)
    assert back.dtype == np.int64
    assert back.tolist() == pts


@settings(max_examples=100)
@given(st.data())
def test_decode_equals_hilbertcurve(data: st.DataObject) -> None:
    n_dims = data.draw(st.integers(1, 10))
    order = data.draw(st.integers(1, 12))
    keys = data.draw(st.lists(st.integers(0, 2 ** (n_dims * order) - 1), min_size=1, max_size=20))
    curve = hc.HilbertCurve(order, n_dims)
    # Python ints in, whatever their width: a list, or an object array for wide keys
    arr = np.array(keys, dtype=np.uint64 if n_dims * order <= 64 else object)
    assert decode(arr, n_dims, order).tolist() == [curve.point_from_distance(k) for k in keys]
    assert decode(keys, n_dims, order).tolist() == [curve.point_from_distance(k) for k in keys]


@pytest.mark.parametrize("n_dims", [1, 2, 3, 5])
def test_order_64_extremes(n_dims: int) -> None:
    top = 2**64 - 1
    rng = np.random.default_rng(n_dims)
    pts = rng.integers(0, top, size=(30, n_dims), dtype=np.uint64, endpoint=True)
    pts[0] = 0
    pts[1] = top
    pts[2, 0] = top
    curve = hc.HilbertCurve(64, n_dims)
    keys = encode(pts, 64)
    assert key_to_int(keys) == [curve.distance_from_point(p) for p in pts.tolist()]
    back = decode(keys, n_dims, 64)
    assert back.dtype == np.uint64
    np.testing.assert_array_equal(back, pts)


def test_list_mixing_small_and_huge_ints_is_exact() -> None:
    # numpy alone would read this list as float64 and lose the low bits of 2**64 - 1
    pts = [[1, 2**64 - 1], [2**63 + 1, 0]]
    curve = hc.HilbertCurve(64, 2)
    assert key_to_int(encode(pts, 64)) == [curve.distance_from_point(p) for p in pts]


def test_paper_grid_32x32_hand_checked_and_against_reference() -> None:
    # the order-1 square, walked by hand: (0,0) -> (0,1) -> (1,1) -> (1,0)
    assert encode([[0, 0], [0, 1], [1, 1], [1, 0]], 1).tolist() == [0, 1, 2, 3]
    cells = np.array([[x, y] for x in range(32) for y in range(32)])
    curve = hc.HilbertCurve(5, 2)
    expected = [curve.distance_from_point(c) for c in cells.tolist()]
    assert encode(cells, 5).tolist() == expected
    assert decode(np.arange(1024), 2, 5).tolist() == [
        curve.point_from_distance(h) for h in range(1024)
    ]


@pytest.mark.parametrize(
    ("n_dims", "order"), [(1, 6), (2, 5), (3, 3), (4, 2), (9, 1), (1, 17), (17, 1), (2, 9), (3, 6)]
)
def test_curve_is_a_hamiltonian_path_of_unit_steps(n_dims: int, order: int) -> None:
    """The definition of a Hilbert curve, independent of any implementation: the keys
    0, 1, 2, ... visit every cell once, each a unit step from the one before. The last four
    grids have more than 2**16 cells: the general path, not the lookup table."""
    size = 2 ** (n_dims * order)
    pts = decode(np.arange(size, dtype=np.uint64), n_dims, order)
    assert (pts >= 0).all() and (pts < 2**order).all()
    assert (np.abs(np.diff(pts, axis=0)).sum(axis=1) == 1).all()
    # encode undoes decode: decode is one-to-one, so the 2**(n*order) keys cover every cell
    np.testing.assert_array_equal(encode(pts, order), np.arange(size, dtype=np.uint64))
    assert (n_dims * order <= LUT_MAX_BITS) == (size <= 2**LUT_MAX_BITS)


def test_wide_keys_sort_compare_and_subtract_as_numbers() -> None:
    n_dims, order = 7, 12  # 84-bit keys
    rng = np.random.default_rng(3)
    pts = rng.integers(0, 2**order, size=(50, n_dims))
    keys = encode(pts, order)
    assert keys.dtype == object and key_bits(n_dims, order) == 84
    ints = key_to_int(keys)
    assert all(type(k) is int for k in ints)
    idx = sort_keys(keys)
    assert [ints[i] for i in idx] == sorted(ints)
    assert np.diff(keys[idx]).tolist() == np.diff(np.array(sorted(ints), dtype=object)).tolist()
    assert max(ints) > 2**64  # really wide, with this seed


def test_sort_keys_is_stable_for_narrow_keys() -> None:
    keys = np.array([5, 3, 5, 1, 3], dtype=np.uint64)
    assert sort_keys(keys).tolist() == [3, 1, 4, 0, 2]
    assert sort_keys(np.array([5, 3, 5, 1, 3], dtype=object)).tolist() == [3, 1, 4, 0, 2]


def test_empty_inputs() -> None:
    assert encode(np.zeros((0, 3), dtype=int), 4).shape == (0,)
    assert encode(np.zeros((0, 30), dtype=int), 4).dtype == object
    assert decode(np.zeros(0, dtype=np.uint64), 3, 4).shape == (0, 3)


def test_integral_floats_are_accepted() -> None:
    assert encode([[3.0, 1.0]], 2).tolist() == encode([[3, 1]], 2).tolist()


@pytest.mark.parametrize(
    ("points", "order", "words"),
    [
        ([[0, 1.5]], 2, ["integers", "1.5", "(0, 1)"]),
        ([[0, np.nan]], 2, ["finite", "(0, 1)"]),
        ([[0, 1], [-1, 0]], 2, [">= 0", "-1", "(1, 0)"]),
        ([[0, 1], [4, 0]], 2, ["< 4", "(1, 0)", "order 2"]),
        ([0, 1, 2], 2, ["shape", "(3,)", "reshape"]),
        (np.zeros((2, 2, 2), dtype=int), 2, ["shape", "(2, 2, 2)"]),
        (np.zeros((2, 0), dtype=int), 2, ["n_dims >= 1"]),
        ([[True, False]], 2, ["boolean"]),
        ([["a", "b"]], 2, ["integer array", "dtype"]),
        ([[1, 2], [3]], 2, ["could not read"]),
        ([[1, 2]], 0, ["order", "1..64"]),
        ([[1, 2]], 65, ["order", "1..64"]),
        ([[1, 2]], 2.0, ["order", "integer"]),
        ([[1, 2]], True, ["order", "integer"]),
        ([[2**60, 0.0]], 63, ["2**53"]),
        (np.array([[1, "x"]], dtype=object), 3, ["integers", "'x'", "(0, 1)"]),
    ],
)
def test_encode_rejects_bad_input(points: object, order: object, words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        encode(points, order)  # type: ignore[arg-type]
    for w in words:
        assert w in str(err.value)


@pytest.mark.parametrize(
    ("keys", "n_dims", "order", "words"),
    [
        ([0, 16], 2, 2, ["< 16", "(1,)"]),
        ([0, -1], 2, 2, [">= 0", "(1,)"]),
        ([[0, 1]], 2, 2, ["shape", "(1, 2)"]),
        ([0.5], 2, 2, ["integers"]),
        ([2**70], 2, 35, ["< 1180591620717411303424", "(0,)"]),
        ([1], 0, 2, ["n_dims"]),
        ([1], 2, 70, ["order"]),
    ],
)
def test_decode_rejects_bad_input(keys: object, n_dims: int, order: int, words: list[str]) -> None:
    with pytest.raises(InputError) as err:
        decode(keys, n_dims, order)  # type: ignore[arg-type]
    for w in words:
        assert w in str(err.value)


def test_key_helpers_reject_bad_keys() -> None:
    with pytest.raises(InputError, match="shape"):
        sort_keys(np.zeros((2, 2), dtype=np.uint64))
    with pytest.raises(InputError, match=">= 0"):
        key_to_int(np.array([3, -(2**70)], dtype=object))
    with pytest.raises(InputError, match="integers"):
        key_to_int([1.5])


def test_max_order_and_grid_dtype() -> None:
    assert MAX_ORDER == 64
    assert grid_dtype(63) == np.int64 and grid_dtype(64) == np.uint64


# --------------------------------------------------------------------------- quantize


def test_quantize_hand_worked_cells() -> None:
    # [0, 1] cut into 32 cells of width 1/32 (exact binary fractions: no round-off)
    x = np.array([[0.0], [1 / 32], [0.5 - 2**-20], [0.5], [1 - 2**-20], [1.0], [-0.25], [1.5]])
    grid, outside = quantize(x, 0.0, 1.0, 5)
    assert grid[:, 0].tolist() == [0, 1, 15, 16, 31, 31, 0, 31]
    assert outside.tolist() == [False] * 6 + [True, True]
    assert grid.dtype == np.int64


def test_quantize_per_dimension_bounds() -> None:
    x = np.array([[-2.0, 10.0], [0.0, 12.0], [1.0, 14.0], [2.0, 9.0]])
    grid, outside = quantize(x, [-2.0, 10.0], [2.0, 14.0], 2)
    # dimension 0: cells of width 1 from -2; dimension 1: cells of width 1 from 10
    assert grid.tolist() == [[0, 0], [2, 2], [3, 3], [3, 0]]
    assert outside.tolist() == [False, False, False, True]


@given(
    st.lists(
        st.tuples(st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=30
    ),
    st.integers(1, 12),
)
def test_quantize_cells_contain_the_points(rows: list[tuple[float, ...]], order: int) -> None:
    x = np.array(rows)
    lo, hi = np.array([-4.0, -5.0, -1.0]), np.array([4.0, 5.0, 3.0])
    grid, outside = quantize(x, lo, hi, order)
    assert outside.tolist() == [bool(((r < lo) | (r > hi)).any()) for r in x]
    width = (hi - lo) / 2**order
    clipped = np.clip(x, lo, hi)
    # the cell [lo + g w, lo + (g + 1) w] holds the point, up to round-off at the edges
    assert (lo + grid * width <= clipped + 1e-12).all()
    assert (clipped <= lo + (grid + 1) * width + 1e-12).all()
    assert encode(grid, order).shape == (len(rows),)


@pytest.mark.parametrize(
    ("x", "lower", "upper", "words"),
    [
        ([[0.0, np.nan]], 0.0, 1.0, ["finite", "(0, 1)"]),
        ([0.0, 1.0], 0.0, 1.0, ["shape", "(2,)"]),
        ([[0.0, 1.0]], [0.0, 1.0], [1.0, 1.0], ["lower must be < upper", "dimension 1"]),
        ([[0.0, 1.0]], [0.0, 0.0, 0.0], 1.0, ["lower", "shape (2,)"]),
        ([[0.0, 1.0]], 0.0, np.inf, ["upper", "finite"]),
    ],
)
def test_quantize_rejects_bad_input(
    x: object, lower: object, upper: object, words: list[str]
) -> None:
    with pytest.raises(InputError) as err:
        quantize(x, lower, upper, 5)  # type: ignore[arg-type]
    for w in words:
        assert w in str(err.value)


@settings(max_examples=40)
@given(st.data())
def test_fast_paths_equal_hilbertcurve(data: st.DataObject) -> None:
    """Magic-number spreading (2-D up to order 32, 3-D up to 21), the scalar path of a few
    points, two-word keys, and unchecked calls all give hilbertcurve's keys."""
    n_dims, order = data.draw(st.sampled_from([(2, 32), (3, 21), (2, 17), (3, 9), (5, 13),
                                               (8, 10), (6, 10), (2, 5)]))
    m = data.draw(st.integers(1, SCALAR_MAX_POINTS + 3))
    pts = data.draw(st.lists(st.lists(st.integers(0, 2**order - 1), min_size=n_dims,
                                      max_size=n_dims), min_size=m, max_size=m))
    ref = [int(k) for k in hc.HilbertCurve(order, n_dims).distances_from_points(pts)]
    arr = np.array(pts, dtype=np.uint64 if order == 32 else np.int64)
    assert key_to_int(encode(arr, order)) == ref
    assert key_to_int(encode(arr, order, validate=False)) == ref
    words = encode_words(arr, order)
    assert words.shape == (m, -(-n_dims * order // 64)) and words.dtype == np.uint64
    assert [int("".join(f"{int(w):064b}" for w in row), 2) for row in words] == ref


@settings(max_examples=60)
@given(grids(), st.sampled_from(["uint8", "int16", "int32", "uint32", "int64", "uint64"]),
       st.booleans())
def test_table_path_of_every_integer_dtype_and_layout_equals_hilbertcurve(
        case: tuple[int, int, list[list[int]]], dtype: str, strided: bool) -> None:
    # the table path (keys of <= 16 bits) reads narrow and strided integer arrays directly:
    # one pass for the bounds, shifts into one index array, the gather written over it
    n_dims, order, pts = case
    if n_dims * order > LUT_MAX_BITS or (dtype == "uint8" and order > 8):
        return
    arr = np.array(pts, dtype=dtype)
    if strided:  # every other column of a wider array: a non-contiguous view
        wide = np.zeros((arr.shape[0], 2 * n_dims), dtype=dtype)
        wide[:, ::2] = arr
        arr = wide[:, ::2]
    curve = hc.HilbertCurve(order, n_dims)
    want = [curve.distance_from_point(p) for p in pts]
    assert encode(arr, order).tolist() == want
    assert arr.tolist() == pts  # the input is left as it was
    if dtype.startswith("int"):
        bad = arr.copy()
        bad[-1, -1] = -1
        with pytest.raises(InputError):
            encode(bad, order)
    big = arr.astype(np.int64)
    big[0, 0] = 2**order
    with pytest.raises(InputError):
        encode(big, order)


@pytest.mark.parametrize(("dtype", "order"), [("int8", 8), ("int8", 7), ("int16", 16),
                                              ("int16", 15), ("int32", 31)])
def test_negative_coordinates_are_refused_at_the_dtypes_full_width(dtype: str,
                                                                   order: int) -> None:
    """A negative signed value sets the top bit, which lies inside [0, 2**order) once the order
    reaches the dtype's width: it must still be refused, never keyed as 0."""
    with pytest.raises(InputError):
        encode(np.array([[-1], [3]], dtype=dtype), order)
