"""Bloom: boundary-dominant flower blooming simulation (Li et al. 2015) as a batch pipeline.

The library: geometry, growth, physics, artifacts and rendering helpers. No Click here;
the commands live in ``stages/``.
"""

__version__ = "0.1.0"
