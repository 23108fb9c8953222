"""Level-1 preparation of an exposure before fitting: reference pixels, saturation
flags, linearisation, IPC deconvolution, common mode and read noise."""

__all__ = []
