"""The thesis's comparisons on the simulated rig: excitation methods, FRF estimators in closed loop, odd
versus full multisines (:mod:`.thesis`, ``ambid compare``)."""
