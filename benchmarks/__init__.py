"""Benchmarks run by ``make bench``; each module ``bench_*.py`` has a ``main() -> None``.

Every benchmark measures its baseline in the same run and prints ratios against it, since
the machines are small and noisy; results are recorded in ``docs/benchmarks.md``.
"""
