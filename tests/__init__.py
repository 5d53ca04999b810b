"""The test suite: a folder per aectorch subpackage (tests/sim/ tests aectorch/sim/), the tests of the
top-level modules (baselines, evaluate, figures, profiling) here beside them, whole runs checked end to end
in end_to_end/, and the repository's own checks (layering, static gates, docs, README, examples,
packaging, scripts, benchmarks) in project/. The folders are packages, so a test module is imported by
its full name (``tests.runtime.test_train``) and basenames may repeat across folders."""
