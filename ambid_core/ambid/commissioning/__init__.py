"""Commissioning: a controller designed for the plant a run measured, and what it will do.

From an identification's updated physical model with its parameters' posterior (and the fitted model),
:mod:`~ambid.commissioning.plants` draws the plants the data allow; :mod:`~ambid.commissioning.structured_tuning`
tunes the per-axis structured controller (PID, lead/lag, low-pass, notches) and
:mod:`~ambid.commissioning.hinf_tuning` the H-infinity mixed-sensitivity one on them;
:mod:`~ambid.commissioning.limits` checks the control current and its noise against the amplifier;
:mod:`~ambid.commissioning.prediction` predicts the input-sensitivity peak the verifying identification
will measure, as an interval and ISO 14839-3 zone probabilities; :mod:`~ambid.commissioning.tuning`
puts them together.
"""
