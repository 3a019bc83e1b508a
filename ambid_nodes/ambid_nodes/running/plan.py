"""The plan of a session, decided once per run, and what its layouts (composed, hardware, processes) share.

:class:`SessionConfig` says what to run, :func:`plan_session` decides the rig, the controller and the
design once (:class:`SessionPlan`), :func:`session_samples` where the experiment starts and how long the
run is; :func:`run_facts` is what every layout returns (:meth:`ambid_nodes.running.layout.Layout.run`).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ambid.control.kinds import ControllerDesign, checked_design
from ambid.excitation import ExcitationDesign
from ambid.excitation.spec import DesignSpec
from ambid.hardware.bridge_protocol import PROTOCOL_VERSION
from ambid.plant.rig import Rig, rig_or_default

from ambid_nodes.running.domain import DEFAULT_NAMESPACE

LIFT_OFF_S = 0.5  # levitate and settle before the experiment starts


@dataclass
class SessionConfig:
    """What to run. Defaults: the main job of ``ambid identify``; the experiment's are
    :class:`ambid.excitation.spec.DesignSpec`'s (the one home of the experiment's defaults)."""

    out_dir: Path = Path("identify")
    # the excitation experiment; its seed also seeds the sensor noise, so one seed makes the session
    experiment: DesignSpec = field(default_factory=DesignSpec)
    rig_file: str = ""
    controller: str = ""  # a kind or a controller file; empty: the rig file's controller, else pid
    nonlinear_magnets: bool = True
    estimator: str = "indirect"
    # at speed a multisine steers clear of the synchronous harmonics; None: the rig's rotor_speed_rpm
    speed_rpm: float | None = None
    namespace: str = DEFAULT_NAMESPACE
    progress: bool = True
    hardware: str = ""      # HOST:PORT of a real-time target: hardware_bridge replaces plant_sim and the controller
    local_port: int = 0     # with hardware: the bridge's UDP port (0: any)
    key_file: str = ""      # with hardware: the rig's key file (protocol version 3)
    protocol_version: int = PROTOCOL_VERSION  # with hardware: 3 authenticated, 2 unauthenticated
    true_model: str = ""    # with hardware: the C target's model file, the truth the FRF is compared with
    session: int = 0        # the session's id (docs/sessions.md); 0: open nodes
    processes: bool = False  # every node its own process, supervised
    # > 0: the loop alone (plant and controller, or the bridge) for this long [s], no experiment, recording or
    # estimate (``ambid graph``); the experiment's seed then seeds the sensor noise only
    loop_seconds: float = 0.0
    live_port: int | None = None    # a Foxglove live view on this port (0: any free one); None: none
    live_host: str = "127.0.0.1"    # the address the live view binds
    # the report: True written before the run returns; "background" by a detached process, the run returning
    # without it (report/status.json says when it is there: ambid identify answers without waiting for it)
    report: bool | str = True
    extra: dict = field(default_factory=dict)
    # the simulated sensor noise's own seed; None: the experiment's. A verifying run repeats the experiment
    # (its lines and phases) and meets fresh noise, as on a real rig
    noise_seed: int | None = None

    @property
    def seed(self) -> int:
        """The simulated sensor noise's seed."""
        return self.experiment.seed if self.noise_seed is None else self.noise_seed

    def design(self, fs_hz: float, rig_speed_rpm: float = 0.0, inputs: Sequence[str] = ()) -> ExcitationDesign:
        """The experiment's design at the plant's rate, on the plant's currents ``inputs`` unless the experiment
        names its own; at speed (a multisine only) steered clear of the synchronous harmonics."""
        speed = rig_speed_rpm if self.speed_rpm is None else self.speed_rpm
        return self.experiment.build(fs_hz, speed if self.experiment.kind == "multisine" else 0.0,
                                     *([inputs] if inputs else []))


@dataclass(frozen=True)
class SessionPlan:
    """What a session runs, each decided once per run and handed to the nodes that need it.

    Attributes:
        rig: the rig, its file parsed once (plant_sim, position_controller, excitation_generator and the
            hardware bridge take this object instead of parsing ``rig_file`` each).
        controller: the position controller, designed and checked against the rig once; None where a
            real-time target closes the loop.
        design: the excitation experiment's design, built once (the generator builds none of its own); None
            where the loop runs alone (``SessionConfig.loop_seconds``).
    """

    rig: Rig
    controller: ControllerDesign | None
    design: ExcitationDesign | None


class NodeDied(RuntimeError):
    """A node of a processes-layout session died before its run was over (ambid_nodes.supervisor).

    Attributes:
        death: {node, how, sample_index, simulated_s, consequence}.
        mcap_path: the recording.
        complete: the recording was closed completely (else ``ambid inspect --recover`` reads it).
        messages: messages recorded (as the recorder or the file says).
        figures: the levitation figures up to there (``ambid.plant.levitation``).
    """

    def __init__(self, death: dict, mcap_path: str, complete: bool, messages: int | None, figures: dict) -> None:
        super().__init__(f"{death['node']} {death['how']} at sample {death['sample_index']}")
        self.death, self.mcap_path, self.complete, self.messages, self.figures = (death, mcap_path, complete,
                                                                                   messages, figures)


def plan_session(cfg: SessionConfig, rig: Rig | None = None, controller: ControllerDesign | None = None
                 ) -> SessionPlan:
    """The plan of ``cfg``: ``rig`` (None: ``cfg.rig_file`` parsed, or the default rig) and ``controller``
    (None: ``cfg.controller`` designed and checked) as given, the design built. ValueError or OSError
    names what cannot be used."""
    rig = rig if rig is not None else rig_or_default(cfg.rig_file)
    if controller is None and not cfg.hardware:
        controller = checked_design(cfg.controller, rig)
    if cfg.loop_seconds:
        return SessionPlan(rig, controller, None)
    return SessionPlan(rig, controller, cfg.design(rig.sample_rate_hz, float(rig.rotor_speed_rpm), rig.layout.inputs))


class ProgressBar:
    """One terminal line: simulated time, periods done, current FRF noise level."""

    def __init__(self, enabled: bool, stream=None) -> None:
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream   # the stream of now (a caller may watch it)
        self.last = 0.0

    def show(self, fraction: float, text: str, force: bool = False) -> None:
        now = time.monotonic()
        if not self.enabled or (not force and now - self.last < 0.25):
            return
        self.last = now
        n = 30
        done = int(round(max(0.0, min(1.0, fraction)) * n))
        self.stream.write(f"\r[{'#' * done}{'.' * (n - done)}] {100 * fraction:5.1f}% {text}\x1b[K")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def session_samples(design: ExcitationDesign | None, fs: float, loop_seconds: float = 0.0) -> tuple[int, int]:
    """(the experiment's first sample index, the session's samples): lift-off, the experiment, and one
    block of tail so the last period is measured. A free-running target can be told the count
    (ambp_udp_target --samples) so it stops where the session does. Without a design, the loop alone:
    (0, ``loop_seconds`` of samples)."""
    if design is None:
        return 0, int(round(loop_seconds * fs))
    start_index = int(round(LIFT_OFF_S * fs))
    return start_index, start_index + design.total_samples + 1000


def run_facts(answer, plant_summary: dict, recorder: dict, live_frf: dict, wall_s: float, layout: str,
              design: ExcitationDesign, mcap_path, foreign: dict, final_estimate_at: float | None = None) -> dict:
    """What a session's run returns for its offline identification (either layout); ``final_estimate_at``:
    when the consumer had the final FRF (time.perf_counter), where known."""
    return {
        "experiment_id": answer.experiment_id,
        "start_index": answer.start_index,
        "plant": plant_summary,
        "recorder": recorder,
        "live_frf": live_frf,
        "wall_s": wall_s,
        "simulated_s": plant_summary["simulated_s"],
        "samples_per_wall_s": plant_summary["samples"] / wall_s,
        "loop_samples_per_wall_s": plant_summary["samples_per_wall_s"],
        "layout": layout,
        "design": design,
        "mcap_path": str(mcap_path),
        "foreign_publishers": foreign,
        "final_estimate_at": final_estimate_at,
    }


def hardware_summary(bridge: dict, total: int, fs: float, wall_s: float) -> dict:
    """The bridge's summary in the terms of plant_sim's (samples, state, failure), with its figures kept."""
    out = {**bridge, "simulated_s": bridge["samples"] / fs, "samples_per_wall_s": bridge["samples"] / wall_s,
           "levitated": None}  # the target keeps the rotor up; the bridge cannot tell
    if bridge["state"] != "done" or bridge["samples"] < total:
        out["failure"] = {"code": "target", "text": (
            f"the target ended {bridge['target_state']} after {bridge['samples']} of {total} samples "
            f"(silent episodes {bridge['silent_episodes']}, {bridge['missing_samples']} samples lost)")}
    return out


def config_json(cfg: SessionConfig) -> dict:
    """The config as JSON values (the recording's session facts say what ran)."""
    d = asdict(cfg)
    d["out_dir"] = str(cfg.out_dir)
    return d
