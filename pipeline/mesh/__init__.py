"""Geometry functions over plain arrays, one public function per module.

In the style of gpytoolbox: each function takes ``vertices (V, 3) float`` and
``faces (F, 3) int`` (and whatever else it needs) and returns arrays or a small named
tuple of arrays; none modifies its inputs. Tolerances are relative to the part's size,
so a model in centimetres and the same model in metres give the same answer.

- :func:`pipeline.mesh.thickness.thickness`: per-face distance to the surface behind,
  and whether a part is a thin shell;
- :func:`pipeline.mesh.midsurface.midsurface`: the open sheet halfway between the two
  sides of a thin shell (a solidified, boxed, tubular or two-layer petal);
- :func:`pipeline.mesh.lobes.lobes`: which petal of a ring each face belongs to, for
  petals joined in one surface at a hub;
- :func:`pipeline.mesh.heightfield.height_sheet`: a petal's sheet sampled as heights over
  its plane, for surfaces with no clean mid-surface (a coarse cage, hems, a crumpled shell);
- :mod:`pipeline.mesh.repair`: small repairs (fans split at pinched vertices, non-manifold
  edges resolved, slits zipped, bowtie fans dropped).
"""

from pipeline.mesh.heightfield import HeightSheet, height_sheet
from pipeline.mesh.lobes import Lobes, lobes
from pipeline.mesh.midsurface import Midsurface, midsurface
from pipeline.mesh.thickness import Thickness, thickness

__all__ = ["HeightSheet", "Lobes", "Midsurface", "Thickness", "height_sheet", "lobes", "midsurface",
           "thickness"]
