"""The feedback loop of plant and controller: closing it and checking it.

Sign convention: u = ic + r with ic = K y (K carries the minus sign), so the
loop from the excitation r to the plant input u is S_i = (I - K P)^-1, the
input sensitivity.
"""

from __future__ import annotations

import numpy as np

from ambid.statespace import StateSpace


def close_loop(plant_d: StateSpace, controller: StateSpace) -> StateSpace:
    """Closed loop r -> [y; u] of a discrete plant (u -> y, D = 0) and controller (y -> ic).

    Returns a discrete StateSpace with inputs r (m) and outputs y (p) then u (m).
    """
    if plant_d.dt <= 0 or abs(plant_d.dt - controller.dt) > 1e-15:
        raise ValueError(f"close_loop: plant and controller must be discrete with one sample period "
                         f"(plant dt={plant_d.dt}, controller dt={controller.dt})")
    if np.any(plant_d.d):
        raise ValueError("close_loop: the discrete plant must be strictly proper (D = 0)")
    ap, bp, cp = plant_d.a, plant_d.b, plant_d.c
    ak, bk, ck, dk = controller.a, controller.b, controller.c, controller.d
    # u = ck xk + dk cp xp + r
    a = np.block([[ap + bp @ dk @ cp, bp @ ck], [bk @ cp, ak]])
    b = np.vstack([bp, np.zeros((ak.shape[0], bp.shape[1]))])
    c = np.vstack([np.hstack([cp, np.zeros((cp.shape[0], ak.shape[0]))]), np.hstack([dk @ cp, ck])])
    d = np.vstack([np.zeros((cp.shape[0], bp.shape[1])), np.eye(bp.shape[1])])
    return StateSpace(a, b, c, d, plant_d.dt, plant_d.input_names,
                      plant_d.output_names + plant_d.input_names)


def check_stability(plant: StateSpace, controller: StateSpace, label: str) -> np.ndarray:
    """Closed-loop poles (z-plane) of ``plant`` (continuous or discrete) with ``controller``.

    Raises:
        ValueError naming the unstable poles (as s-plane frequency and damping)
        when the loop is unstable.
    """
    plant_d = plant if plant.dt > 0 else plant.to_discrete(controller.dt)
    loop = close_loop(plant_d, controller)
    poles = loop.poles()
    bad = poles[np.abs(poles) >= 1.0]
    if bad.size:
        s = np.log(bad.astype(complex)) / controller.dt
        desc = ", ".join(f"z={z:.4f} (s={v.real:+.1f}{v.imag:+.1f}j rad/s, {abs(v) / (2 * np.pi):.1f} Hz)"
                         for z, v in zip(bad, s))
        raise ValueError(f"{label}: the closed loop is unstable; unstable poles: {desc}. "
                         "Retune the controller or check the rig parameters.")
    return poles
