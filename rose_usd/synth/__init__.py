"""Seeded synthetic tabletop cases with full ground truth (``rose-usd bench generate``)."""
