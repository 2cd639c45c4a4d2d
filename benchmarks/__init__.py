"""On-demand benchmarks of maglevid (``python -m benchmarks.<name>``); never run as tests."""
