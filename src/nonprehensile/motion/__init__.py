"""The motion model (paper Section VI): preprocessing, the Hilbert index, clustering, store."""

from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.motion.hilbert import (
    MAX_ORDER,
    decode,
    encode,
    key_to_int,
    quantize,
    sort_keys,
)
from nonprehensile.motion.store import MemoryStore, SampleStore, SQLiteStore, StoreError
from nonprehensile.motion.trajectory import (
    DEFAULT_N_POINTS,
    crop,
    fill_gaps,
    flatten,
    preprocess,
    preprocess_many,
    resample,
    unflatten,
)

__all__ = [
    "DEFAULT_N_POINTS",
    "MAX_ORDER",
    "HilbertClusterer",
    "MemoryStore",
    "SQLiteStore",
    "SampleStore",
    "StoreError",
    "crop",
    "decode",
    "encode",
    "fill_gaps",
    "flatten",
    "key_to_int",
    "preprocess",
    "preprocess_many",
    "quantize",
    "resample",
    "sort_keys",
    "unflatten",
]
