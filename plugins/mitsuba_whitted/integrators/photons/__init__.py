"""Progressive photon mapping for the ``whitted`` integrator (``photons``):

- :mod:`.emission`: each emitter's share of a pass's photons, aimed from a
  light at a point at the shapes that bend light;
- :mod:`.tracing`: photon paths a bounce at a time, and the photons they
  leave on smooth surfaces;
- :mod:`.grid`: the photons in a hashed grid, and the density estimate
  around a point;
- :mod:`.progressive`: the passes, their shrinking radii and the visible
  points of the ray tree.
"""
