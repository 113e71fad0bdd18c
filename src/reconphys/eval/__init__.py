"""Evaluation: metrics (DESIGN §9), methods and reports."""
