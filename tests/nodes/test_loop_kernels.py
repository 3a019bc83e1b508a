"""The loop nodes' compiled per-sample paths (loop_kernels' C entry points, called as the nodes call
them through loop_call) against their Python paths."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from ambid.control.lqg import LqgParameters, lqg_controller
from ambid.control.pid import PidParameters, pid_controller
from ambid.control.stepper import ControllerStepper
from ambid.plant.rig import make_rig
from ambid_nodes.loop_call import BoundKernel
from ambid_nodes.loop_kernels import (CK_LEAD, CK_LIMIT, CK_MAT, CK_N, CK_P, CK_Q, CK_SLOTS, CK_WORK, LOOP_OUT, N_CK,
                                      N_PK, PK_BLOCK_START, PK_CLOCK_EVERY, PK_FREE_UNTIL, PK_LOOP, PK_R, PK_R_FIRST,
                                      PK_WORK, controller_kernel, plant_kernel, sample_buffer)
from ambid_nodes.sample_codec import encode_sample

RIGS = {"radial": {}, "five_axis": {"axial_bearing": 1}}  # the default rig, and the five-axis machine


def steppers(kind: str, rig=None):
    rig = make_rig() if rig is None else rig
    model = (pid_controller(PidParameters(), rig.dt, rig.layout) if kind == "pid"
             else lqg_controller(rig, LqgParameters()))
    return ControllerStepper(model, 3.0), ControllerStepper(model, 3.0)


def controller_call(stepper: ControllerStepper, ahead: bool, out: bytearray):
    """The controller's compiled path bound to ``stepper`` as position_controller binds it: call(data, k)."""
    w, n, mat, limit = stepper.kernel_args(ahead)
    fast = BoundKernel(controller_kernel, N_CK)
    fast.bind(CK_WORK, w, np.float64)
    fast.bind(CK_SLOTS, out, np.uint8)  # both answer slots: every answer lands in out
    fast.bind(CK_SLOTS + 2, out, np.uint8)
    fast.set(CK_N, n)
    fast.set(CK_P, stepper.n_inputs)
    fast.set(CK_Q, stepper.n_outputs)
    fast.set(CK_MAT, mat)
    fast.set_float(CK_LIMIT, limit)
    fast.set(CK_LEAD, int(ahead))
    return fast.call


@pytest.mark.parametrize("rig", list(RIGS))
@pytest.mark.parametrize("kind", ["pid", "lqg"])
@pytest.mark.parametrize("ahead", [True, False])
def test_compiled_answers_are_the_python_answers(kind, ahead, rig):
    ref, fast = steppers(kind, make_rig(RIGS[rig]))
    na = ref.n_inputs
    out = sample_buffer(na)
    answer = controller_call(fast, ahead, out)
    rng = np.random.default_rng(3)
    for k in range(300):
        y = list(rng.normal(0.0, 20e-6, na))  # large enough to saturate some answers
        ic = ref.step_ahead(y) if ahead else ref.step(y)
        assert answer(encode_sample(k, y), k) == 1
        assert bytes(out) == encode_sample(k + int(ahead), ic)
    assert np.array_equal(fast.x, ref.x)


def _sample(index, *values):
    return encode_sample(index, list(values))


def test_anything_but_the_awaited_valid_sample_changes_nothing():
    _, fast = steppers("pid")
    w, n, mat, limit = fast.kernel_args(True)
    out = sample_buffer(4)
    answer = controller_call(fast, True, out)
    good = _sample(7, 1e-6, 2e-6, 3e-6, 4e-6)
    bad = {
        "wrong index": _sample(8, 1e-6, 2e-6, 3e-6, 4e-6),
        "NaN": _sample(7, 1e-6, math.nan, 3e-6, 4e-6),
        "+inf": _sample(7, math.inf, 2e-6, 3e-6, 4e-6),
        "+inf and -inf": _sample(7, math.inf, -math.inf, 3e-6, 4e-6),
        "3 values": encode_sample(7, [1e-6, 2e-6, 3e-6]),
        "5 values": encode_sample(7, [1e-6] * 5),
        "big-endian header": b"\x00\x00\x00\x00" + good[4:],
        "short": good[:51],
        "long": good + b"\x00",
        "count field 4 + 2**8": good[:12] + struct.pack("<I", 4 + 256) + good[16:],
        "index beyond 2**63": good[:4] + struct.pack("<Q", 2**63 + 7) + good[12:],
    }
    before = w.copy()
    kept = np.ones(len(w), dtype=bool)
    kept[n:n + 4] = False  # the input slot: scratch, y is parsed into it
    for what, data in bad.items():
        out[:] = bytes(len(out))
        assert answer(data, 7) == 0, what
        assert np.array_equal(w[kept], before[kept]) and not any(out), what
    assert answer(bytearray(good), 7) == 1  # any buffer, not only the bytes a subscription hands over
    assert answer(memoryview(_sample(8, 1e-6, 2e-6, 3e-6, 4e-6)), 8) == 1


@pytest.mark.parametrize("rig_name", list(RIGS))
def test_compiled_plant_sample_is_the_python_step(rig_name):
    """From rest on the retainer (contact), through lift-off, with clipping and excitation: the compiled
    plant path records, publishes and steps exactly what step_output does, and says when a sample
    boundary (clock, full block, end of the excitation block) or an excitation lookup is due."""
    from ambid.plant.simulator import PlantSimulator
    from ambid_nodes.loop_kernels import (PLANT_AFTER, PLANT_CLIPPED, PLANT_CONTACT, PLANT_KIND, PLANT_LOOKUP,
                                          PLANT_NOISE, PLANT_STEPPED, plant_loop_vector)

    rig = make_rig(RIGS[rig_name])
    na = len(rig.layout)
    ref, fast = PlantSimulator(rig, seed=4, nonlinear_magnets=True), PlantSimulator(rig, seed=4,
                                                                                    nonlinear_magnets=True)
    ctl = ControllerStepper(pid_controller(PidParameters(), rig.dt, rig.layout), 3.0)
    rows = np.random.default_rng(1).normal(0.0, 1.5, (64, na))  # excitation, some of it beyond the limit
    block, clock_every = 50, 7
    lp, cur, rec = plant_loop_vector(block, na)
    out = sample_buffer(na)
    kernel = BoundKernel(plant_kernel, N_PK)  # bound as plant_sim binds it
    kernel.bind(PK_WORK, fast.work, np.float64)
    kernel.bind(PK_LOOP, lp, np.float64)
    kernel.bind(LOOP_OUT, out, np.uint8)
    kernel.set(PK_CLOCK_EVERY, clock_every)

    def plant_sample(data, k, rows, first, free_until, block_start):
        kernel.bind(PK_R, rows, np.float64, na, writes=False)
        kernel.set(PK_R_FIRST, first)
        kernel.set(PK_FREE_UNTIL, free_until)
        kernel.set(PK_BLOCK_START, block_start)
        return kernel.call(data, k)

    cur[:na] = y = fast.output()
    codes = set()
    for k in range(6000):
        assert np.array_equal(y, ref.output())
        ic = ctl.step(y)
        # before 3000: no excitation (free until 3000); from 3000 on, 64-sample blocks, looked up per block
        excited = k >= 3000
        r = rows[k % 64] if excited else np.zeros(na)
        *y_ref, clipped, contact = ref.step_output(*(np.asarray(ic) + r))
        data = encode_sample(k, ic)
        first = k - k % 64 if excited and k % 64 else -100  # the block in use; at a block's start, none yet
        code = plant_sample(data, k, rows, first, 3000, k - k % block)
        if excited and k % 64 == 0:
            assert code == PLANT_LOOKUP
            code = plant_sample(data, k, rows, k, 3000, k - k % block)
        if code == PLANT_NOISE:
            fast.draw_noise()
            code = plant_sample(data, k, rows, first, 3000, k - k % block)
        codes.add(code & ~PLANT_AFTER)
        assert bool(code & PLANT_CLIPPED) == clipped and (code & PLANT_KIND == PLANT_CONTACT) == contact
        due = (k + 1) % clock_every == 0 or (k + 1) % block == 0 or (excited and (k + 1) % 64 == 0)
        assert bool(code & PLANT_AFTER) == due, k
        assert np.array_equal(rec[k % block], np.concatenate([y, np.asarray(ic) + r, ic, r]))
        if code & PLANT_KIND == PLANT_CONTACT:
            cur[:na] = y = np.array(fast.finish_contact_sample())  # the caller finishes it (as plant_sim)
        else:
            assert code & PLANT_KIND == PLANT_STEPPED
            assert bytes(out) == encode_sample(k + 1, y_ref)
            y = cur[:na].copy()
        assert np.array_equal(y, y_ref)
    assert np.array_equal(fast.x, ref.x)
    assert {PLANT_STEPPED, PLANT_CONTACT, PLANT_STEPPED | PLANT_CLIPPED} <= codes
    # a message that is not the awaited valid sample changes nothing
    before, lp_before, out_before = fast.work.copy(), lp.copy(), bytes(out)
    kept = np.ones(len(lp), dtype=bool)
    kept[2 * na:3 * na] = False  # scratch: the values being parsed
    for data in (encode_sample(6001, [0.0] * na), encode_sample(6000, [math.nan] + [0.0] * (na - 1)),
                 encode_sample(6000, [0.0] * (na - 1))):   # and one value short
        assert plant_sample(data, 6000, rows, -100, 10**9, 6000) == 0
        assert np.array_equal(fast.work, before) and np.array_equal(lp[kept], lp_before[kept])
        assert bytes(out) == out_before


def test_a_bound_kernel_refuses_what_its_kernel_would_misread():
    fast = BoundKernel(controller_kernel, N_CK)
    bad = {"float32": (np.zeros(8, np.float32), np.float64, None, True),
           "strided": (np.zeros(16)[::2], np.float64, None, True),
           "read-only where the kernel writes": (np.frombuffer(bytes(64)), np.float64, None, True),
           "3 columns for 4": (np.zeros((5, 3)), np.float64, 4, False),
           "1-D for 2-D": (np.zeros(8), np.float64, 4, False),
           "a list": ([0.0] * 8, np.float64, None, True)}
    for what, (arr, dtype, columns, writes) in bad.items():
        with pytest.raises(ValueError, match=f"word {CK_WORK} needs"):
            fast.bind(CK_WORK, arr, dtype, columns, writes)
        assert not fast.context.any(), what  # nothing half-bound
    ro = np.frombuffer(bytes(64)).reshape(2, 4)
    fast.bind(CK_WORK, ro, np.float64, 4, writes=False)  # the kernel only reads it: fine
    assert fast.context[CK_WORK] == ro.ctypes.data and fast.context[CK_WORK + 1] == 2
    out = sample_buffer(4)
    fast.bind(LOOP_OUT, out, np.uint8)
    with pytest.raises(BufferError):
        out.extend(b"x")  # a bound bytearray cannot move under the kernel
    with pytest.raises(TypeError, match="two positional arguments"):
        fast.call(b"")
    with pytest.raises(TypeError):
        fast.call(1.5, 0)  # not a buffer
    with pytest.raises(OverflowError):
        fast.call(b"", 2**64)
