"""On-demand benchmarks (``python -m benchmarks.<name>``); never run as timed tests."""
