"""Offline rates: a session's FRF beside a bare read of the same MCAP file, and the fit of its FRF matrix.

The session file is written here from a core-level simulation, not by the
graph (seconds instead of minutes for the long ones): the linearised true
rig (:func:`ambid.plant.true_rig.true_linear_model`) in closed loop with the
default PID, driven by the experiment's excitation, with white sensor noise
of the rig on the recorded y (not fed back). The file holds what the
recorder writes of those topics, serialised as the nodes publish them:
``measurement`` blocks (the plant's y, u, ic, r of every axis of the rig, 1000 samples each),
``excitation`` blocks, the ``excitation/design`` message and ``/clock`` every
100 samples, zstd-compressed chunks as the recorder's default.
"""

from __future__ import annotations

import json
import os
import statistics
import time
from collections.abc import Callable

import numpy as np
from ambid.control.closed_loop import close_loop
from ambid.control.pid import PidParameters, pid_controller
from ambid.excitation import ExcitationDesign
from ambid.excitation.spec import DesignSpec
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.recording import SessionWriter, iter_messages
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock

from ambid_msgs.msg import ExcitationDesign as DesignMsg
from ambid_msgs.msg import SampleBlock
from ambid_nodes import qos
from ambid_nodes.conversions import block_msg, time_msg

NAMESPACE = "/amb"
EXPERIMENT_ID = "bench"
def make_design(**overrides) -> ExcitationDesign:
    """The default identify experiment (:class:`ambid.excitation.spec.DesignSpec`) at the default rig's sample
    rate, with DesignSpec field overrides."""
    return DesignSpec(**overrides).build(make_rig().sample_rate_hz)


def _design_msg(d: ExcitationDesign, start: int, dt: float) -> DesignMsg:
    return DesignMsg(stamp=time_msg(start * dt), experiment_id=EXPERIMENT_ID, kind=d.kind,
                     multi_input=str(d.options.get("mimo", "")), start_index=start, total_samples=d.total_samples,
                     sample_rate=d.fs_hz, samples_per_period=d.n_per_period, n_periods=d.n_periods,
                     n_transient_periods=d.n_transient_periods, n_realisations=d.n_realisations,
                     n_experiments=d.n_experiments, input_names=list(d.input_names),
                     excited_lines=d.excited_lines.tolist(), measurement_time=d.total_samples / d.fs_hz,
                     seed=int(d.seed or 0), design_json=json.dumps(d.to_dict()))


def write_simulated_session(path: str | os.PathLike, design: ExcitationDesign, start_index: int = 1000,
                            tail_samples: int = 1000, seed: int = 0, block_size: int = 1000,
                            compression: str = "zstd") -> dict:
    """Write a session MCAP of ``design`` run on the linearised default rig (see the module docstring).

    Args:
        path: output .mcap file (replaced).
        design: the experiment; its inputs must be among the rig's (u_<axis>), fs = the rig's.
        start_index: sample index where the experiment starts.
        tail_samples: samples recorded after the experiment.
        seed: seed of the sensor noise.
        block_size: samples per measurement / excitation block.
        compression: chunk compression of the file.

    Returns:
        dict with ``samples`` (measurement samples), ``file_bytes``, ``messages``, ``simulated_s``.
    """
    rig = make_rig()
    dt = rig.dt
    if abs(design.fs_hz * dt - 1.0) > 1e-9:
        raise ValueError(f"design sample rate {design.fs_hz} Hz differs from the rig's {rig.sample_rate_hz:g} Hz")
    lay = rig.layout
    na = len(lay)
    cols = [lay.inputs.index(name) for name in design.input_names]
    units = lay.units("y") + lay.units("u") + lay.units("ic") + lay.units("r")
    loop = close_loop(true_linear_model(rig, discrete=True), pid_controller(PidParameters(), dt, lay))  # r -> [y; u]
    a, b, c, d = loop.a, loop.b, loop.c, loop.d
    rng = np.random.default_rng(seed)
    noise_m = rig.values["sensor_noise_m"]
    end_exc = start_index + design.total_samples
    n_total = end_exc + tail_samples
    x = np.zeros(a.shape[0])
    messages = 0
    with SessionWriter(path, compression=compression, overwrite=True) as w:
        for topic, type_name, profile in (("measurement", "ambid_msgs/msg/SampleBlock", qos.BLOCKS),
                                          ("excitation", "ambid_msgs/msg/SampleBlock", qos.BLOCKS),
                                          ("excitation/design", "ambid_msgs/msg/ExcitationDesign", qos.LATCHED)):
            w.add_topic(f"{NAMESPACE}/{topic}", type_name, [profile])
        w.add_topic("/clock", "rosgraph_msgs/msg/Clock", [qos.CLOCK])
        w.write(f"{NAMESPACE}/excitation/design", serialize_message(_design_msg(design, start_index, dt)), 0)
        messages += 1
        for first in range(0, n_total, block_size):
            n = min(block_size, n_total - first)
            r = np.zeros((n, na))
            lo, hi = max(first, start_index), min(first + n, end_exc)
            if lo < hi:
                r[lo - first:hi - first, cols] = design.samples(lo - start_index, hi - lo)
                exc = block_msg(lo, dt, lay.excitations, lay.units("r"), r[lo - first:hi - first],
                                experiment_id=EXPERIMENT_ID)
                w.write(f"{NAMESPACE}/excitation", serialize_message(exc), int(first * dt * 1e9))
                messages += 1
            xs = np.empty((n, x.size))
            for k in range(n):  # the state recursion is sequential; everything else per block
                xs[k] = x
                x = a @ x + b @ r[k]
            yu = xs @ c.T + r @ d.T
            y = yu[:, :na] + noise_m * rng.standard_normal((n, na))
            u = yu[:, na:]
            data = np.hstack([y, u, u - r, r])
            for k in range(first + (-first % 100), first + n, 100):
                w.write("/clock", serialize_message(Clock(clock=time_msg(k * dt))), int(k * dt * 1e9))
                messages += 1
            final = SampleBlock.FLAG_FINAL if first + n == n_total else 0
            meas = block_msg(first, dt, lay.measurement_names, units, data, np.zeros(n, np.uint8), final)
            w.write(f"{NAMESPACE}/measurement", serialize_message(meas), int((first + n) * dt * 1e9))
            messages += 1
    return {"samples": n_total, "file_bytes": os.path.getsize(path), "messages": messages,
            "simulated_s": n_total * dt}


def _read_mcap_bare(path: str | os.PathLike) -> int:
    from mcap.reader import make_reader

    n = 0
    with open(path, "rb") as f:
        for _schema, _channel, message in make_reader(f).iter_messages():
            n += len(message.data)
    return n


def _read_session_messages(path: str | os.PathLike) -> int:
    return sum(len(m.data) for m in iter_messages(path))


def _frf(path: str | os.PathLike) -> int:
    from ambid.frf.offline import frf_from_session

    return int(frf_from_session(path).frf.size)


def offline_figures(path: str | os.PathLike, samples: int, repeats: int = 3) -> dict:
    """Time the FRF of a session and bare reads of the same file, interleaved.

    Every reader runs once untimed first (imports, file cache), so that no round
    times one reader's first call against the others' later ones.

    Args:
        path: session .mcap file.
        samples: measurement samples in it (for samples/s).
        repeats: rounds; each times every reader once (the order rotating).

    Returns:
        dict reader -> {``s`` (median wall time), ``mb_per_s`` (file MB per s), ``samples_per_s``}
        for ``mcap_bare`` (the mcap library's iter_messages, nothing done with the data),
        ``session_iter`` (:func:`ambid.recording.iter_messages`, all topics) and ``frf``
        (:func:`ambid.frf.offline.frf_from_session`), plus ``ratio_frf_to_bare`` (rate of frf over
        mcap_bare, median over rounds), ``ratio_frf_to_session_iter`` (the same over ambid's own
        reader: what the FRF costs beyond reading with it) and ``file_bytes``.
    """
    size = os.path.getsize(path)
    readers: dict[str, Callable] = {"mcap_bare": _read_mcap_bare, "session_iter": _read_session_messages,
                                    "frf": _frf}
    names = list(readers)
    for name in names:
        readers[name](path)
    times: dict[str, list[float]] = {k: [] for k in names}
    ratios, ratios_own = [], []
    for r in range(repeats):
        this = {}
        for name in names[r % len(names):] + names[:r % len(names)]:
            t0 = time.perf_counter()
            readers[name](path)
            this[name] = time.perf_counter() - t0
            times[name].append(this[name])
        ratios.append(this["mcap_bare"] / this["frf"])
        ratios_own.append(this["session_iter"] / this["frf"])
    out: dict = {"file_bytes": size, "samples": samples}
    for name, ts in times.items():
        t = statistics.median(ts)
        out[name] = {"s": t, "mb_per_s": size / 1e6 / t, "samples_per_s": samples / t, "all_s": ts}
    out["ratio_frf_to_bare"] = statistics.median(ratios)
    out["ratio_frf_to_session_iter"] = statistics.median(ratios_own)
    return out


def fit_figures(n_lines: int = 2000, order: int = 24) -> dict:
    """Time the common-denominator fit of a noisy synthetic 4x4 AMB plant FRF (ambid.fit.benchmark)."""
    from ambid.fit.benchmark import benchmark_fit

    return benchmark_fit(n_lines=n_lines, order=order)
