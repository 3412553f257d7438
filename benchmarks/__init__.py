"""The benchmarks of jaxpose: speed, accuracy, scaling, float32, P3P, gradients, robust.

Each module is a script (`python benchmarks/run.py --quick`, or `python -m
benchmarks.run --quick`) and importable (`from benchmarks import speed`); `_harness`
holds what they share (machine description, timing, workers, problems, JSON output).
Results go to `benchmarks/results/`.
"""
