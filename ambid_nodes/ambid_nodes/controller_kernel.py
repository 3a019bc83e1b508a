"""The controller node's per-sample message path as one compiled call.

y[k] arrives as the 52 bytes of a 4-channel ``ambid_msgs/Sample`` (layout in
:mod:`ambid_nodes.sample_codec`); the answer goes out as the same. Parsing,
the state-space step and packing in Python cost ~6 us a sample; here they
are one numba call (~2.5 us). Only a message that is exactly what the loop
awaits takes this path: the CDR header, 4 values, the awaited index, all
finite. Anything else returns 0 and leaves everything untouched, and the
node's Python path decides and says why (:func:`sample_codec.decode_sample`).
"""

from __future__ import annotations

import numba
import numpy as np
from numba import types

from ambid.step_kernels import statespace_step

SAMPLE4_BYTES = 52


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
    b = np.frombuffer(data, dtype=np.uint8)
    if b.shape[0] != SAMPLE4_BYTES or b[0] != 0 or b[1] != 1 or b[2] != 0 or b[3] != 0:
        return 0
    if b[12] != 4 or b[13] != 0 or b[14] != 0 or b[15] != 0:
        return 0
    idx = np.uint64(0)
    for i in range(8):
        idx |= np.uint64(b[4 + i]) << np.uint64(8 * i)
    if expected < 0 or idx != np.uint64(expected):
        return 0
    y = b[20:52].copy().view(np.float64)  # after 4 bytes of padding: float64 aligned in the CDR body
    t = y[0] + y[1] + y[2] + y[3]
    if not (t - t == 0.0):  # a non-finite value (or a finite sum that overflows: the slow path decides)
        return 0
    for i in range(4):
        w[n + i] = y[i]
    statespace_step(w, n, 4, 4, mat, limit)
    ans = np.uint64(expected + lead)
    out[0] = 0
    out[1] = 1
    out[2] = 0
    out[3] = 0
    for i in range(8):
        out[4 + i] = (ans >> np.uint64(8 * i)) & np.uint64(0xFF)
    out[12] = 4
    for i in range(13, 20):
        out[i] = 0
    bits = w[n + 4:n + 8].copy().view(np.uint64)
    for j in range(4):
        v = bits[j]
        for i in range(8):
            out[20 + 8 * j + i] = (v >> np.uint64(8 * i)) & np.uint64(0xFF)
    return 1


ANSWER_SAMPLE4_ARGS = (numba.float64[::1], numba.int64, numba.int64, numba.float64,
                       types.Bytes(types.uint8, 1, "C", readonly=True), numba.int64, numba.int64, numba.uint8[::1])
