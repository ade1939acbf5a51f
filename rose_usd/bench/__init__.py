"""The benchmark: seeded suites of synthetic cases with ground truth, perception modes that turn
ground truth into the inputs real tools give, metrics, and the paper's Table 2 / Table 3 report."""
