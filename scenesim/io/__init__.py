"""Files: the exposure (uncal), truth and slope files, written and read."""

__all__ = []
