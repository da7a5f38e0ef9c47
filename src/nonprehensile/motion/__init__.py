"""The motion model (paper Section VI): trajectory preprocessing and the Hilbert index."""

from nonprehensile.motion.hilbert import (
    MAX_ORDER,
    decode,
    encode,
    key_to_int,
    quantize,
    sort_keys,
)
from nonprehensile.motion.trajectory import (
    DEFAULT_N_POINTS,
    crop,
    fill_gaps,
    flatten,
    preprocess,
    resample,
    unflatten,
)

__all__ = [
    "DEFAULT_N_POINTS",
    "MAX_ORDER",
    "crop",
    "decode",
    "encode",
    "fill_gaps",
    "flatten",
    "key_to_int",
    "preprocess",
    "quantize",
    "resample",
    "sort_keys",
    "unflatten",
]
