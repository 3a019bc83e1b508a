"""Chapter 2's linearised model of a rig, what an engineer writes down from the drawing
(Hynynen 2011, eqs. 2.16-2.24); the true rig the simulator runs is :mod:`ambid.plant.true_rig`."""

from __future__ import annotations

import numpy as np

from ambid.channels import CURRENT_NAMES, DISPLACEMENT_NAMES
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

    Args:
        rig: rig parameters.
        n_bending: bending modes per plane; None takes ``rig.bending_modes``
            (0 gives the rigid 4-DOF rotor of sec. 2.3.1).

    Returns:
        StateSpace, dt = 0, 4 inputs (CURRENT_NAMES) and 4 outputs
        (DISPLACEMENT_NAMES); states: rotor states, then coil control
        currents [A].
    """
    rotor = rig.rotor_model(n_bending)
    ki, ks = rig.magnet.ki, rig.magnet.ks
    tau = 1.0 / (2 * np.pi * rig.current_loop_bandwidth_hz)
    n = rotor.n_states
    i4 = np.eye(4)
    a = np.block([[rotor.a + ks * rotor.b @ rotor.c_bearing, ki * rotor.b], [np.zeros((4, n)), -i4 / tau]])
    b = np.vstack([np.zeros((n, 4)), i4 / tau])
    c = np.hstack([rotor.c_sensor, np.zeros((4, 4))])
    return StateSpace(a, b, c, np.zeros((4, 4)), 0.0, CURRENT_NAMES, DISPLACEMENT_NAMES,
                      ("A",) * 4, ("m",) * 4)
