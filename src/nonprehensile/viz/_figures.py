"""What every figure module shares: matplotlib, imported only when a figure is drawn."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from nonprehensile.errors import InputError

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["new_figure", "require_matplotlib", "save_figure"]


def require_matplotlib() -> None:
    """Import matplotlib (with its 3-D toolkit) or say which extra to install.

    Raises
    ------
    InputError
        If matplotlib is not installed.
    """
    try:
        import matplotlib.figure  # noqa: F401  (imported to check that it is there)
        import mpl_toolkits.mplot3d  # noqa: F401
    except ImportError:
        raise InputError(
            "drawing figures needs matplotlib, which is not installed; install it with "
            "`pip install 'nonprehensile[viz]'`"
        ) from None


def new_figure(**kwargs: Any) -> Figure:
    """A :class:`matplotlib.figure.Figure` (no pyplot state), or an :class:`InputError`."""
    require_matplotlib()
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def save_figure(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Save ``fig`` in the format its suffix names (png, svg, pdf, ...).

    Raises
    ------
    InputError
        An unknown suffix (listing the known ones).
    """
    path = Path(path)
    known = fig.canvas.get_supported_filetypes()
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in known:
        raise InputError(
            f"{path}: cannot write a figure as {suffix or 'a file with no suffix'!r}; use one "
            f"of {', '.join('.' + k for k in sorted(known))}"
        )
    fig.savefig(path, dpi=dpi)
    return path
