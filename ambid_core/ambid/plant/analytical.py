"""Chapter 2's linearised model of a rig, what an engineer writes down from the drawing
(Hynynen 2011, eqs. 2.16-2.24); the true rig the simulator runs is :mod:`ambid.plant.true_rig`."""

from __future__ import annotations

import numpy as np

from ambid.plant.rig import Rig
from ambid.statespace import StateSpace


def analytical_model(rig: Rig, n_bending: int | None = None) -> StateSpace:
    """Chapter 2's linearised model, continuous time: current reference u [A] -> sensor y [m].

    The rotor model (finite-element, modes as in the rig, or the imported
    one), per axis F = ki ic + ks q at the bearing plane (eq. 2.18, nominal
    ki, ks of eqs. 2.16-2.17 at the centre), first-order amplifiers with the
    bandwidth of eq. 2.24, ideal sensors (unit gain, no lag) at the sensor
    planes. No housing, no extra delay; gravity is a constant offset and not
    part of the small-signal model.

    Parameters
    ----------
    rig
        rig parameters.
    n_bending
        bending modes per plane; None takes ``rig.bending_modes``
        (0 gives the rigid 4-DOF rotor of sec. 2.3.1).

    Returns
    -------
    StateSpace, dt = 0, na inputs (the rig layout's u names) and na outputs
    (its y names); states: rotor states, then coil control currents [A].
    With an axial bearing its axis carries the axial magnet's ki, ks and
    amplifier, and the rotor's axial rigid mass (decoupled).
    """
    rotor = rig.rotor_model(n_bending)
    layout = rotor.layout
    na = len(layout)
    mags = rig.axis_magnets()
    ki, ks = np.array([m.ki for m in mags]), np.array([m.ks for m in mags])
    inv_tau = 1.0 / (1.0 / (2 * np.pi * rig.amplifier_bandwidths_hz))
    n = rotor.n_states
    a = np.block([[rotor.a + (rotor.b * ks) @ rotor.c_bearing, rotor.b * ki],
                  [np.zeros((na, n)), -np.diag(inv_tau)]])
    b = np.vstack([np.zeros((n, na)), np.diag(inv_tau)])
    c = np.hstack([rotor.c_sensor, np.zeros((na, na))])
    return StateSpace(a, b, c, np.zeros((na, na)), 0.0, layout.inputs, layout.outputs,
                      layout.units("u"), layout.units("y"))
