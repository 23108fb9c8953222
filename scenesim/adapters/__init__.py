"""Adapters that run other libraries (stcal) on scenesim's files."""

__all__ = []
