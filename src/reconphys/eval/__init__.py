"""Evaluation: metrics (docs/design.md#evaluation), methods and reports."""
