"""The loop nodes' per-sample message paths as one compiled call each.

y[k] and ic[k] travel as the 52 bytes of a 4-channel ``ambid_msgs/Sample``
(layout in :mod:`ambid_nodes.sample_codec`: header, uint64 index, uint32
count, 4 bytes of padding, 4 float64). Parsing, stepping, recording and
packing in Python cost 6-15 us a sample per node; here each is one numba
call. Only a message that is exactly what the loop awaits takes this path:
the CDR header, 4 values, the awaited index, all finite. Anything else
returns 0 and leaves everything untouched, and the node's Python path
decides and says why (:func:`sample_codec.decode_sample`).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from ambid.step_kernels import PAR_STATUS, STATUS_NOISE, plant_step, statespace_step

SAMPLE4_BYTES = 52


@numba.njit(cache=True)
def _parse_sample4(data: bytes, expected: int) -> np.ndarray:
    """The 4 values of the Sample in ``data`` if it is the awaited valid one, else an empty array."""
    none = np.empty(0)
    b = np.frombuffer(data, dtype=np.uint8)
    if b.shape[0] != SAMPLE4_BYTES or b[0] != 0 or b[1] != 1 or b[2] != 0 or b[3] != 0:
        return none
    if b[12] != 4 or b[13] != 0 or b[14] != 0 or b[15] != 0:
        return none
    idx = np.uint64(0)
    for i in range(8):
        idx |= np.uint64(b[4 + i]) << np.uint64(8 * i)
    if expected < 0 or idx != np.uint64(expected):
        return none
    v = b[20:52].copy().view(np.float64)  # after 4 bytes of padding: float64 aligned in the CDR body
    t = v[0] + v[1] + v[2] + v[3]
    if not (t - t == 0.0):  # a non-finite value (or a finite sum that overflows: the slow path decides)
        return none
    return v


@numba.njit(cache=True)
def _pack_sample4(index: int, values: np.ndarray, out: np.ndarray) -> None:
    """The Sample (index, values (4,)) into out (52,) uint8."""
    ans = np.uint64(index)
    out[0] = 0
    out[1] = 1
    out[2] = 0
    out[3] = 0
    for i in range(8):
        out[4 + i] = (ans >> np.uint64(8 * i)) & np.uint64(0xFF)
    out[12] = 4
    for i in range(13, 20):
        out[i] = 0
    bits = values.copy().view(np.uint64)
    for j in range(4):
        v = bits[j]
        for i in range(8):
            out[20 + 8 * j + i] = (v >> np.uint64(8 * i)) & np.uint64(0xFF)


@numba.njit(cache=True)
def answer_sample4(w: np.ndarray, n: int, mat: int, limit: float, data: bytes, expected: int, lead: int,
                   out: np.ndarray) -> int:
    """Step the controller with the Sample y[expected] in ``data`` and pack the answer into ``out``.

    Args:
        w, n, mat, limit: the controller's work vector, state count, step-matrix offset and
            output saturation (:meth:`ambid.controller.ControllerStepper.kernel_args`).
        data: the serialised Sample (52 bytes expected).
        expected: the sample index awaited.
        lead: the answer carries index expected + lead (1: pipelined, ic[k+1]; 0: ic[k]).
        out: (52,) uint8, receives the answer Sample's bytes.

    Returns:
        1 if ``data`` was the awaited valid sample (state stepped, ``out`` written), else 0
        (nothing changed).
    """
    y = _parse_sample4(data, expected)
    if y.shape[0] == 0:
        return 0
    for i in range(4):
        w[n + i] = y[i]
    statespace_step(w, n, 4, 4, mat, limit)
    _pack_sample4(expected + lead, w[n + 4:n + 8], out)
    return 1


ANSWER_SAMPLE4_ARGS = (numba.float64[::1], numba.int64, numba.int64, numba.float64,
                       types.Bytes(types.uint8, 1, "C", readonly=True), numba.int64, numba.int64, numba.uint8[::1])


# plant_sample4's return codes (bit 4 adds: the amplifiers clipped u)
PLANT_NOT_TAKEN = 0  # not the awaited valid sample: nothing changed
PLANT_STEPPED = 1  # free flight: the row recorded, cur and out hold y[k+1]
PLANT_CONTACT = 2  # the rotor touches: the row recorded, the sample started; the caller finishes it
PLANT_NOISE = 3  # the noise block is used up: nothing changed, the caller's Python path steps
PLANT_CLIPPED = 4


@numba.njit(cache=True)
def plant_sample4(s: np.ndarray, data: bytes, expected: int, r_rows: np.ndarray, r_row: int, rec: np.ndarray,
                  row: int, cur: np.ndarray, out: np.ndarray) -> int:
    """Step the simulated plant with the Sample ic[expected] in ``data`` and the excitation r.

    Args:
        s: the plant work vector (:attr:`ambid.simulator.PlantSimulator.work`).
        data: the serialised Sample (52 bytes expected).
        expected: the sample index k the plant steps.
        r_rows, r_row: r[k] [A] is r_rows[r_row] ((m, 4) float64).
        rec: (block_size * 12,) float64, the block's rows of y[k], ic[k], r[k]; row k goes at ``row``.
        cur: (8,) float64, y[k] [m] (published) and the last ic [A]; y becomes y[k+1].
        out: (52,) uint8, receives the Sample y[k+1].

    Returns:
        One of PLANT_NOT_TAKEN, PLANT_STEPPED, PLANT_CONTACT, PLANT_NOISE, plus PLANT_CLIPPED
        when stepped and the amplifiers saturated.
    """
    ic = _parse_sample4(data, expected)
    if ic.shape[0] == 0:
        return PLANT_NOT_TAKEN
    r0, r1, r2, r3 = r_rows[r_row, 0], r_rows[r_row, 1], r_rows[r_row, 2], r_rows[r_row, 3]
    y0, y1, y2, y3, clipped, contact = plant_step(s, ic[0] + r0, ic[1] + r1, ic[2] + r2, ic[3] + r3)
    if contact and s[PAR_STATUS] == STATUS_NOISE:
        return PLANT_NOISE
    o = 12 * row
    for i in range(4):
        rec[o + i] = cur[i]
        rec[o + 4 + i] = ic[i]
        cur[4 + i] = ic[i]
    rec[o + 8] = r0
    rec[o + 9] = r1
    rec[o + 10] = r2
    rec[o + 11] = r3
    flag = PLANT_CLIPPED if clipped else 0
    if contact:
        return PLANT_CONTACT + flag
    cur[0] = y0
    cur[1] = y1
    cur[2] = y2
    cur[3] = y3
    _pack_sample4(expected + 1, cur[0:4], out)
    return PLANT_STEPPED + flag


PLANT_SAMPLE4_ARGS = (numba.float64[::1], types.Bytes(types.uint8, 1, "C", readonly=True), numba.int64,
                      numba.float64[:, ::1], numba.int64, numba.float64[::1], numba.int64, numba.float64[::1],
                      numba.uint8[::1])
