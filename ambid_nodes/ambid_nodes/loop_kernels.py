"""The loop nodes' per-sample message paths as one compiled call each.

y[k] and ic[k] travel as an ``ambid_msgs/Sample`` of the rig's na channels,
20 + 8 na bytes (layout in :mod:`ambid_nodes.sample_codec`: header, uint64
index, uint32 count, 4 bytes of padding, na float64; 52 bytes for four
axes). Parsing, stepping, recording and packing in Python cost 6-15 us a
sample per node; here each is one compiled call. Only a message that is
exactly what the loop awaits takes this path: the CDR header, na values,
the awaited index, all finite. Anything else returns 0 and changes nothing
but a scratch slot for the parsed values, and the node's Python path
decides and says why (:func:`sample_codec.decode_sample`).

The C entry points ``plant_kernel`` and ``controller_kernel`` (numba cfuncs
of type ``LOOP_KERNEL``) are called with the message and k only, by the loop
pump (:mod:`ambid_nodes.loop_pump`) or through :mod:`ambid_nodes.loop_call`:
the buffers they work on are named in a context vector of int64 words
(``LOOP_*``, then ``PK_*`` or ``CK_*``: an array's address, then its length). Through numba's Python entry point the same call cost 1-4 us, most
of it boxing each array argument, against ~0.4 us of arithmetic.
"""

from __future__ import annotations

import numba
import numpy as np
from ambid.control.step_kernel import statespace_step
from ambid.plant.step_kernel import PAR_N, PAR_NA, PAR_STATUS, STATUS_NOISE, plant_offsets, plant_step
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

SAMPLE_HEAD_BYTES = 20  # CDR encapsulation (4), uint64 index, uint32 count, 4 bytes of padding


def sample_bytes(n_values: int) -> int:
    """The size of a serialised Sample of ``n_values`` values [bytes]."""
    return SAMPLE_HEAD_BYTES + 8 * n_values


@numba.njit(cache=True)
def _parse_sample(b: np.ndarray, n: int, expected: int, dest: np.ndarray, at: int) -> bool:
    """Whether the bytes ``b`` (uint8) are the awaited valid Sample of n values; its values are copied to
    dest[at:at + n] (float64 scratch, also when False) once header, count and index are right."""
    if b.shape[0] != SAMPLE_HEAD_BYTES + 8 * n or b[0] != 0 or b[1] != 1 or b[2] != 0 or b[3] != 0:
        return False
    if b[12] != n or b[13] != 0 or b[14] != 0 or b[15] != 0:
        return False
    idx = np.uint64(0)
    for i in range(8):
        idx |= np.uint64(b[4 + i]) << np.uint64(8 * i)
    if expected < 0 or idx != np.uint64(expected):
        return False
    # the values follow 4 bytes of padding: aligned in the CDR body, not in memory, so copied
    v = dest[at:at + n].view(np.uint8)
    for i in range(8 * n):
        v[i] = b[SAMPLE_HEAD_BYTES + i]
    t = 0.0
    for j in range(n):
        t += dest[at + j]
    return t - t == 0.0  # False: a non-finite value (or a finite sum that overflows: the slow path decides)


@numba.njit(cache=True)
def _pack_sample(index: int, values: np.ndarray, out: np.ndarray) -> None:
    """The Sample (index, values (n,)) into out (20 + 8 n,) uint8."""
    ans = np.uint64(index)
    n = values.shape[0]
    out[0] = 0
    out[1] = 1
    out[2] = 0
    out[3] = 0
    for i in range(8):
        out[4 + i] = (ans >> np.uint64(8 * i)) & np.uint64(0xFF)
    out[12] = n
    for i in range(13, 20):
        out[i] = 0
    bits = values.view(np.uint64)  # values: contiguous
    for j in range(n):
        v = bits[j]
        for i in range(8):
            out[SAMPLE_HEAD_BYTES + 8 * j + i] = (v >> np.uint64(8 * i)) & np.uint64(0xFF)


@numba.njit(cache=True)
def answer_sample(w: np.ndarray, n: int, p: int, q: int, mat: int, limit: float, data: np.ndarray, expected: int,
                  lead: int, out: np.ndarray) -> int:
    """Step the controller with the Sample y[expected] in ``data`` and pack the answer into ``out``.

    Args:
        w, n, mat, limit: the controller's work vector, state count, step-matrix offset and
            output saturation (:meth:`ambid.control.stepper.ControllerStepper.kernel_args`).
        p, q: its inputs (y) and outputs (ic).
        data: the serialised Sample, uint8 (20 + 8 p bytes expected).
        expected: the sample index awaited.
        lead: the answer carries index expected + lead (1: pipelined, ic[k+1]; 0: ic[k]).
        out: uint8 (20 + 8 q), receives the answer Sample's bytes.

    Returns:
        1 if ``data`` was the awaited valid sample (state stepped, ``out`` written), else 0
        (state and output unchanged; w's input slot may hold the refused values).
    """
    if not _parse_sample(data, p, expected, w, n):  # y goes to the input slot w[n:n + p]
        return 0
    statespace_step(w, n, p, q, mat, limit)
    _pack_sample(expected + lead, w[n + p:n + p + q], out)
    return 1


# the plant's loop vector (:func:`plant_loop_vector`): the compiled path's float64 buffers in one array (one
# context entry), for na axes:
#   lp[0:2 na]          cur: y[k] [m] as published, and the last current taken [A]
#   lp[2 na:3 na]       scratch, the values of the message being parsed
#   lp[3 na:]           the measurement block, a row of 4 na per sample: y [m], u = ic + r (as applied
#                       before saturation), ic, r [A], na each


def plant_loop_vector(block_size: int, n_axes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plant loop vector of ``n_axes`` axes for blocks of ``block_size`` samples, zeroed, and its two views.

    Returns:
        (lp, cur, rec): lp (3 na + 4 na block_size,) float64; cur (2 na,); rec (block_size, 4 na).
    """
    na = int(n_axes)
    lp = np.zeros(3 * na + 4 * na * block_size)
    return lp, lp[:2 * na], lp[3 * na:].reshape(block_size, 4 * na)


def sample_buffer(n_values: int) -> bytearray:
    """The buffer a compiled path packs its Sample of ``n_values`` values into, published as it is."""
    return bytearray(sample_bytes(n_values))


# plant_sample's return codes: a kind in the low 3 bits, plus flags
PLANT_NOT_TAKEN = 0  # not the awaited valid sample: nothing changed
PLANT_STEPPED = 1  # free flight: the row recorded, cur and out hold y[k+1]
PLANT_CONTACT = 2  # the rotor touches: the row recorded, the sample started; the caller finishes it
PLANT_NOISE = 3  # the noise block is used up: nothing changed, the caller's Python path steps
PLANT_LOOKUP = 4  # r[k] is neither in r_rows nor zero before free_until: nothing changed, look it up
PLANT_KIND = 7
PLANT_CLIPPED = 8  # stepped, and the amplifiers saturated u
PLANT_AFTER = 16  # stepped, and the caller has a sample boundary to serve: /clock, a full block or
# the end of the excitation block


@numba.njit(cache=True)
def plant_sample(s: np.ndarray, data: np.ndarray, expected: int, r_rows: np.ndarray, r_first: int, free_until: int,
                 lp: np.ndarray, row: int, clock_every: int, out: np.ndarray) -> int:
    """Step the simulated plant with the Sample ic[expected] in ``data`` and the excitation r.

    Args:
        s: the plant work vector (:attr:`ambid.plant.simulator.PlantSimulator.work`) of na axes.
        data: the serialised Sample, uint8 (20 + 8 na bytes expected).
        expected: the sample index k the plant steps.
        r_rows, r_first: the excitation block in use, r[r_first + i] = r_rows[i] [A] ((m, na) float64).
        free_until: r[k] = 0 for k < free_until outside the block in use.
        lp: the plant loop vector (:func:`plant_loop_vector`): y[k] is in cur and row k goes to
            rec[row]; cur then holds y[k+1].
        row: k's row in the block, < block_size.
        clock_every: /clock is due after samples k with (k + 1) % clock_every == 0.
        out: uint8 (20 + 8 na), receives the Sample y[k+1] when stepped in free flight.

    Returns:
        One of the PLANT_* kinds; when stepped, plus PLANT_CLIPPED and PLANT_AFTER as they apply.
    """
    na = int(s[PAR_NA])
    i = expected - r_first
    excited = 0 <= i < r_rows.shape[0]
    if excited:
        after = i + 1 == r_rows.shape[0]
    elif expected < free_until:
        after = False
    else:
        return PLANT_LOOKUP
    ic_at = 2 * na
    if not _parse_sample(data, na, expected, lp, ic_at):
        return PLANT_NOT_TAKEN
    uin = plant_offsets(int(s[PAR_N]), na)[3]
    rec = 3 * na + 4 * na * row
    for j in range(na):
        r = r_rows[i, j] if excited else 0.0
        ic = lp[ic_at + j]
        u = ic + r
        s[uin + j] = u
        lp[rec + j] = lp[j]            # y[k] as published
        lp[rec + na + j] = u
        lp[rec + 2 * na + j] = ic
        lp[rec + 3 * na + j] = r
    clipped, contact = plant_step(s)
    if contact and s[PAR_STATUS] == STATUS_NOISE:
        return PLANT_NOISE
    for j in range(na):
        lp[na + j] = lp[ic_at + j]   # the last current taken
    code = PLANT_CLIPPED if clipped else 0
    if after or (expected + 1) % clock_every == 0 or 3 * na + 4 * na * (row + 1) == lp.shape[0]:
        code += PLANT_AFTER
    if contact:
        return PLANT_CONTACT + code
    yout = uin + na
    for j in range(na):
        lp[j] = s[yout + j]
    _pack_sample(expected + 1, lp[0:na], out)
    return PLANT_STEPPED + code


# -- the C entry points ------------------------------------------------------
# int64 kernel(const uint8 *data, int64 size, int64 k, int64 *context): what loop_call.LoopCall calls
LOOP_KERNEL = types.int64(types.CPointer(types.uint8), types.int64, types.int64, types.CPointer(types.int64))

# the words every loop kernel's context starts with: what the loop pump (_loop_pump.c) reads
LOOP_K = 0  # the sample index the next message must carry, passed to the kernel as k
LOOP_GATE = 1  # 0: the pump hands every message to the node's Python path
LOOP_LIMIT = 2  # the pump runs the kernel only for k < limit
LOOP_COUNT = 3  # messages the pump answered (accepted; the node's tally counts them too)
LOOP_OUT = 4  # the bytes the kernel packs its answer into (uint8), published when it returns LOOP_DONE
N_LOOP = 6
LOOP_DONE = 1  # the kernel took the message and packed the answer; nothing else to do
LOOP_NO_LIMIT = 2**62

# plant_kernel's context words (after the LOOP_* words); an array takes two, its address and its
# length (rows for r). It packs y[k+1] into LOOP_OUT; PLANT_STEPPED is LOOP_DONE.
PK_WORK = 6  # the plant work vector (float64)
PK_LOOP = 8  # the plant loop vector (float64, plant_loop_vector)
PK_R = 10  # the excitation block in use, (rows, na) float64
PK_R_FIRST = 12  # its first sample index
PK_FREE_UNTIL = 13  # r[k] = 0 for k < free_until outside the block in use
PK_BLOCK_START = 14  # the sample index of the measurement block's row 0
PK_CLOCK_EVERY = 15  # /clock after samples k with (k + 1) % clock_every == 0
N_PK = 16

# controller_kernel's context words (after the LOOP_* words); it packs the answer into LOOP_OUT
CK_WORK = 6  # the controller work vector (float64, ControllerStepper.kernel_args)
CK_N = 8  # state count
CK_MAT = 9  # step-matrix offset in the work vector
CK_LIMIT = 10  # output saturation [A], the bits of a float64
CK_LEAD = 11  # the answer to y[k] is ic[k + lead]
CK_STATUS_EVERY = 12  # answering y[k] with k % status_every == 0 returns CONTROLLER_STATUS (0: never)
# the answers to the last two displacements: the answer to y[k] is packed into slot k % 2 (uint8, 20 + 8 q
# bytes each), which LOOP_OUT then names; a plant that asks again for y[k] or y[k - 1] gets it re-sent
CK_SLOTS = 13  # slot 0 (address, length), then slot 1 at CK_SLOTS + 2
CK_P = 17  # the controller's inputs p (displacements in a Sample)
CK_Q = 18  # its outputs q (currents in the answer)
N_CK = 19
CONTROLLER_ANSWERED = LOOP_DONE
CONTROLLER_STATUS = 2  # answered, and the node has a status to publish


@intrinsic
def pointer(typingctx, address, dtype):
    """The ``dtype`` pointer at an integer ``address`` (a context word)."""
    if not isinstance(address, types.Integer) or not isinstance(dtype, types.NumberClass):
        return None
    sig = types.CPointer(dtype.instance_type)(address, dtype)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


@intrinsic
def _float_bits(typingctx, word):
    """The float64 whose bits are the int64 ``word``."""
    if not isinstance(word, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(word), codegen


@numba.njit(cache=True)
def _f8(c, word: int) -> np.ndarray:
    return numba.carray(pointer(c[word], np.float64), c[word + 1])


@numba.njit(cache=True)
def _u8(c, word: int) -> np.ndarray:
    return numba.carray(pointer(c[word], np.uint8), c[word + 1])


@numba.cfunc(LOOP_KERNEL, cache=True)
def plant_kernel(data, size, k, c):
    """plant_sample on the buffers of context c (PK_*), for the Sample ic[k] in data[:size]."""
    s = _f8(c, PK_WORK)
    rows = numba.carray(pointer(c[PK_R], np.float64), (c[PK_R + 1], int(s[PAR_NA])))
    return plant_sample(s, numba.carray(data, size), k, rows, c[PK_R_FIRST], c[PK_FREE_UNTIL],
                        _f8(c, PK_LOOP), k - c[PK_BLOCK_START], c[PK_CLOCK_EVERY], _u8(c, LOOP_OUT))


@numba.cfunc(LOOP_KERNEL, cache=True)
def controller_kernel(data, size, k, c):
    """answer_sample on the buffers of context c (CK_*), for the Sample y[k] in data[:size];
    CONTROLLER_STATUS instead of CONTROLLER_ANSWERED where a status is due. The answer goes to
    answer slot k % 2 (CK_SLOTS), which LOOP_OUT names from then on."""
    slot = CK_SLOTS + 2 * (k & 1)
    c[LOOP_OUT] = c[slot]
    c[LOOP_OUT + 1] = c[slot + 1]
    code = answer_sample(_f8(c, CK_WORK), c[CK_N], c[CK_P], c[CK_Q], c[CK_MAT], _float_bits(c[CK_LIMIT]),
                         numba.carray(data, size), k, c[CK_LEAD], _u8(c, LOOP_OUT))
    every = c[CK_STATUS_EVERY]
    if code and every > 0 and k % every == 0:
        return CONTROLLER_STATUS
    return code
