"""Benchmarks (``make bench``): not part of the test suite.

Each module ``tests/benchmarks/bench_<name>.py`` defines ``run() -> list[dict]``. A row
has at least ``name``, ``value``, ``unit`` and may add ``target``, ``peer``, ``ratio``
and ``note``. ``python -m tests.benchmarks [NAME ...]`` runs them, prints one table and
writes ``bench-results.json`` at the repository root.
"""
