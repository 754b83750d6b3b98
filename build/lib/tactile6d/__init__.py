"""tactile6d: 6D object pose from several DIGIT tactile sensors (Caddeo et al., ICRA 2023, rebuilt)."""

__version__ = "0.1.0"
