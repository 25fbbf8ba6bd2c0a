"""Experiments over many runs: ablation suites, their cells and tables, regression checks."""
