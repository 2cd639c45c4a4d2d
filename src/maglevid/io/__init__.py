"""Recordings in and out of files: CSV (+ JSON side-car), NPZ, MATLAB .mat, Parquet."""
