"""Evaluation: scenarios, metrics, the paper's figures, and cross-checks against other receivers."""
