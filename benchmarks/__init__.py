"""aectorch's benchmark suite (pytest tests over `benchmarks.harness`); see docs/performance.md."""
