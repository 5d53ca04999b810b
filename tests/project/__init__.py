"""The repository as a whole: layering, static gates, docs, README, examples, packaging, scripts, benchmarks."""
