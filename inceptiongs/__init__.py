"""InceptionGS: repair badly observed regions of Gaussian-splat scenes by generative
bootstrapping. This package is the method as a library; it imports no GL."""

__version__ = "0.1.0"
