"""Small ready-made models used by examples, tests and benchmarks."""
