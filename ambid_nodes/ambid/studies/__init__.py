"""Whole jobs built from the other packages: identifying a recorded session (identification) and
the thesis's method comparisons (comparison)."""
