"""Exact analytic ray/shape intersection maths, independent of Mitsuba's
shape classes so it can run inside any integrator (or, later, inside a
traced ``ray_intersect_preliminary``)."""
