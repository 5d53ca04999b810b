"""The suite's pytest set-up: the results of a run with ``AECTORCH_BENCH_SAVE`` written at its end,
and pytest-benchmark's ``benchmark`` fixture where the plugin is not installed (one call, as
``--benchmark-disable`` makes it)."""

from __future__ import annotations

import os
import sys

import pytest

from benchmarks import harness

try:
    import pytest_benchmark  # noqa: F401
except ImportError:
    class _OneCall:
        """The fixture's interface without its timing: each call runs the function once."""

        def __init__(self):
            self.extra_info: dict = {}
            self.group = None

        def __call__(self, fn, *args, **kwargs):
            return fn(*args, **kwargs)

        def pedantic(self, fn, args=(), kwargs=None, setup=None, rounds=1, warmup_rounds=0, iterations=1):
            return fn(*args, **(kwargs or {}))

    @pytest.fixture
    def benchmark():
        return _OneCall()


def pytest_sessionfinish(session):
    folder = os.environ.get("AECTORCH_BENCH_SAVE")
    if folder and session.testsfailed == 0 and not hasattr(session.config, "workerinput"):
        for path in harness.save(folder, " ".join(["pytest", *sys.argv[1:]])):
            print(f"\nwrote {path}")
