"""What runs write: a run and its files (`run_files`, the library's entry point for ``pld-slam
run``), and experiments over many runs: ablation suites, their cells and tables, regression checks."""
