"""Up-the-ramp slope fitting: CDS, equal-weight least squares and optimal GLS."""

__all__ = []
