"""Validation report of mitsuba-whitted: integrator comparison, speed against error, numerical stability."""
