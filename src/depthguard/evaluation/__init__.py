"""Evaluation: accuracy against ground truth, placement checks, benchmarks."""
