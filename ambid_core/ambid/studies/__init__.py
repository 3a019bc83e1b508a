"""Whole jobs built from the other packages: identifying a recorded session (identification), the
thesis's method comparisons (comparison) and a measured Campbell diagram over speed (campbell)."""
