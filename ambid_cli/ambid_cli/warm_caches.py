"""Fill the caches the first ``ambid identify`` would otherwise fill: run by ``ambid setup``.

- the compiled per-sample kernels (numba, ``$NUMBA_CACHE_DIR``): the plant's and the
  controller's steps and the loop nodes' C-callable kernels, for the default rig, as the
  session's nodes build them (:mod:`ambid.compiled`);
- the crest-factor phases of identify's default experiment (:mod:`ambid.disk_cache`).

Each step says what it does; nothing here starts ROS. ``python -m ambid_cli.warm_caches``.
"""

from __future__ import annotations

import sys
import time


def _say(text: str) -> None:
    print(f"ambid setup: {text}", file=sys.stderr, flush=True)


def warm() -> float:
    """Compile (or load) every kernel of a default session and design its default experiment;
    returns the wall seconds it took."""
    t0 = time.perf_counter()
    _say("compiling the per-sample kernels (plant, controller, loop nodes); once per version of their sources")
    from ambid.control.kinds import checked_design
    from ambid.control.stepper import ControllerStepper
    from ambid.plant.rig import make_rig
    from ambid.plant.simulator import PlantSimulator

    rig = make_rig()
    sim = PlantSimulator(rig, seed=0, nonlinear_magnets=True)
    sim.step([0.0] * len(rig.layout.inputs))
    design = checked_design("", rig)
    ControllerStepper(design.model, design.current_limit_a).step([0.0] * design.model.n_inputs)
    import ambid_nodes.loop_kernels  # noqa: F401 - its C-callable kernels compile (or load) on import

    _say(f"kernels ready ({time.perf_counter() - t0:.1f} s); designing identify's default experiment "
         "(crest-factor phases, kept for every run)")
    from ambid.excitation.spec import DesignSpec

    DesignSpec().build(float(rig.sample_rate_hz), float(rig.rotor_speed_rpm), rig.layout.inputs)
    return time.perf_counter() - t0


if __name__ == "__main__":
    took = warm()
    _say(f"caches filled in {took:.1f} s")
