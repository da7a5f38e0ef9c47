"""The histogram of Hilbert keys coloured by cluster: the paper's Fig. 12(b).

Each sample (a flattened trajectory) is one Hilbert key; clusters are runs of the sorted keys,
so a histogram of the keys with one colour per cluster shows the clustering at a glance. With
the true classes (the demonstrated skills) a second panel colours the same histogram by class,
to compare.

Keys of at most 16 bits (the paper's 2 components x order 5 = 10 bits: indices 0..1023) are
plotted as they are; wider keys as their position along the curve, ``key / 2**bits`` in
``[0, 1)``. Matplotlib (the ``viz`` extra) is imported inside the functions, which build
:class:`matplotlib.figure.Figure` objects directly and never touch pyplot's global state.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nonprehensile.errors import InputError
from nonprehensile.motion.clustering import HilbertClusterer
from nonprehensile.viz._figures import new_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["cluster_histogram_figure", "plot_key_histogram"]

#: Widest key plotted as a raw index.
_RAW_BITS = 16


def plot_key_histogram(
    ax: Axes,
    keys: ArrayLike,
    groups: Sequence[object] | ArrayLike,
    *,
    n_bits: int,
    bins: int = 64,
    legend_title: str = "cluster",
) -> None:
    """Stacked histogram of keys, one colour per group, on ``ax``.

    Parameters
    ----------
    ax : matplotlib Axes
    keys : array_like of int, shape (n_samples,)
        Hilbert keys (``uint64``, or Python ints).
    groups : sequence, shape (n_samples,)
        The group (cluster id, or true class) of each key.
    n_bits : int
        Bits of a key (``n_components * order``): keys of at most 16 bits are plotted as
        indices ``0 .. 2**n_bits - 1``, wider ones as ``key / 2**n_bits``.
    bins : int
        Number of bins over the whole range of the curve.

    Raises
    ------
    InputError
        If keys and groups differ in length, or a key is negative or too wide.
    """
    k = [int(v) for v in np.asarray(keys, dtype=object).ravel().tolist()]
    g = list(np.asarray(groups, dtype=object).ravel().tolist())
    if len(k) != len(g):
        raise InputError(f"{len(k)} keys but {len(g)} groups; give one group per key")
    if any(v < 0 or v >= 2**n_bits for v in k):
        raise InputError(f"keys must be in 0 .. 2**{n_bits} - 1 (n_bits={n_bits})")
    raw = n_bits <= _RAW_BITS
    x = np.array([float(v) if raw else v / 2.0**n_bits for v in k])
    top = float(2**n_bits) if raw else 1.0
    edges = np.linspace(0.0, top, bins + 1)
    try:
        names = sorted(set(g))
    except TypeError:  # groups of mixed types: keep the order of first appearance
        names = list(dict.fromkeys(g))
    # stacked: each group's counts drawn as one filled step patch on top of the groups
    # before it (ax.hist makes a patch per bar and group: hundreds, slow to draw: issue 16)
    # The patches are added as plain artists: the limits are set below, and letting the axes
    # grow its data limits around each patch walks its outline segment by segment in Python
    # (5 ms a patch: issue 16). They are still the axes' patches, which the legend lists.
    from matplotlib.patches import StepPatch

    below = np.zeros(bins)
    for i, name in enumerate(names):
        counts = np.histogram(x[[gi == name for gi in g]], bins=edges)[0].astype(float)
        # (a baseline array is documented, "float or array-like"; the type stub says float)
        ax.add_artist(StepPatch(below + counts, edges, baseline=below.copy(),  # type: ignore[arg-type]
                                fill=True, facecolor=f"C{i % 10}", linewidth=0,
                                label=str(name)))
        below += counts
    if names:
        ax.set_ylim(0.0, max(1.0, float(below.max())) * 1.05)
        ax.legend(title=legend_title, fontsize="small")
    ax.set_xlim(0.0, top)
    # one scale for every key width, so that histograms of different arcs compare
    ax.set_xlabel("Hilbert index" if raw else "position along the Hilbert curve (0 to 1)")
    ax.set_ylabel("trajectories")


def cluster_histogram_figure(
    clusterer: HilbertClusterer,
    X: ArrayLike | None = None,
    truth: Sequence[object] | None = None,
    *,
    title: str | None = None,
    bins: int = 64,
    labels: ArrayLike | None = None,
) -> Figure:
    """The paper's Fig. 12(b): histogram of the Hilbert keys coloured by cluster.

    Parameters
    ----------
    clusterer : HilbertClusterer
        A fitted clusterer.
    X : array_like, shape (n_samples, n_features), optional
        Samples to show, keyed by ``clusterer.transform`` and clustered by
        ``clusterer.predict``. Default: every stored sample, with its stored key and
        ``labels_``.
    truth : sequence, shape (n_samples,), optional
        The true class of each sample (the demonstrated skill): adds a panel coloured by it.
    title : str, optional
    bins : int
    labels : array_like of int, shape (n_samples,), optional
        The clusters to colour by (e.g. a library's numbering), instead of
        ``clusterer.predict(X)``.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    InputError
        If the clusterer is not fitted, or ``truth`` does not have one entry per sample.
    """
    if not clusterer.n_recalibrations_:
        raise InputError("the clusterer is not fitted yet: fit it before drawing its keys")
    if X is None:
        keys: list[int] | NDArray[np.uint64] = clusterer.store.keys()
        labels = clusterer.labels_ if labels is None else np.asarray(labels)
    else:
        keys = clusterer.transform(X)
        labels = clusterer.predict(X) if labels is None else np.asarray(labels)
    if truth is not None and len(truth) != len(labels):
        raise InputError(
            f"truth has {len(truth)} entries for {len(labels)} samples; give one class per "
            "sample"
        )
    n_bits = clusterer.key_bits_
    rows = 1 if truth is None else 2
    # a fixed layout (inches): each row 2.8 in, of which 0.8 for its title and x labels
    height = 2.8 * rows + 0.5
    fig = new_figure(figsize=(8.0, height))
    axes = [fig.add_axes((0.09, (height - 0.5 - 2.8 * (i + 1) + 0.55) / height, 0.89,
                          2.0 / height)) for i in range(rows)]
    plot_key_histogram(axes[0], keys, labels.tolist(), n_bits=n_bits, bins=bins)
    # titles at a given y: nothing is above these axes, and matplotlib then skips measuring
    # every tick label to find out (milliseconds a title: issue 16)
    axes[0].set_title(f"clusters ({clusterer.method} method, "
                      f"{len(set(np.asarray(labels).tolist()))} clusters)", fontsize="medium",
                      y=1.0)
    if truth is not None:
        plot_key_histogram(axes[1], keys, list(truth), n_bits=n_bits, bins=bins,
                           legend_title="class")
        axes[1].set_title("true classes", fontsize="medium", y=1.0)
        # the panels share their x scale: its numbers and name once, under the lower one
        # (each tick label costs half a millisecond of text layout and drawing: issue 16)
        axes[0].tick_params(axis="x", labelbottom=False)
        axes[0].set_xlabel("")
    if title:
        fig.suptitle(title)
    return fig
