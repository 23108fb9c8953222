"""Grading fits against the injected truth: statistics, photometry and plots."""

__all__ = []
