"""``python -m nonprehensile.cli``: the ``nonprehensile`` script."""

from nonprehensile.cli import run

run()
