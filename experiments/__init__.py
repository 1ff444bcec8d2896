"""Experiments reproducing and extending the thesis's evaluation (see README.md)."""
