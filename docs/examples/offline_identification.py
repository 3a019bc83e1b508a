"""Identify a rig from its own time records with ambid's Python API, no ROS needed.

A rig that logs its displacements, control currents and the excitation added
to them can be identified offline. Here the "rig" is ambid's simulator, run
in plain Python (ambid.control.simulated_loop's closed loop), so the script runs
anywhere ``pip install ./ambid_core`` does; with a real rig, start at step 2
with its record and a MAP.yaml.

    python docs/examples/offline_identification.py [OUT_DIR]

1. design an excitation (identify's orthogonal multisine, shortened) and
   record the closed loop it excites into ``OUT_DIR/rig.npz``;
2. import the record as a session (``OUT_DIR/rig.mcap``) with a MAP.yaml;
3. estimate the FRF, fit a model, print its modes with their 95 % intervals;
4. update the physical model (ki, ks, ...) to the FRF.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import ambid
from ambid.control.simulated_loop import levitate, run_loop

AXES = ("a_x", "b_x", "a_y", "b_y")


def record_rig(out: Path, seed: int = 3) -> tuple[Path, Path]:
    """Step 1: a shortened identify experiment on the simulated rig, as a record and its MAP.yaml."""
    rig = ambid.load_rig()
    design = ambid.design_excitation(band_hz=(10.0, 1000.0), resolution_hz=10.0, n_periods=3,
                                     n_realisations=2, n_transient_periods=1, phases="random", seed=seed)
    lead = 1000  # samples of levitation before the experiment starts
    r = np.zeros((lead + design.total_samples + 500, 4))
    r[lead:lead + design.total_samples] = design.samples(0, design.total_samples)
    rec = run_loop(levitate(rig, seed=seed), r)
    columns = {f"y_{a}": rec.y[:, i] for i, a in enumerate(AXES)}
    columns |= {f"u_{a}": rec.u[:, i] for i, a in enumerate(AXES)}
    columns |= {f"r_{a}": rec.r[:, i] for i, a in enumerate(AXES)}
    np.savez(out / "rig.npz", **columns)
    (out / "rig.MAP.yaml").write_text(
        f"sample_rate_hz: {rig.sample_rate_hz}\n"
        + "".join(f"{group}: {{{', '.join(f'{p}_{a}: {{column: {p}_{a}}}' for a in AXES)}}}\n"
                  for group, p in (("outputs", "y"), ("currents", "u"), ("excitation", "r")))
        + f"transient_periods: {design.n_transient_periods}\nband_hz: [10, 1000]\n")
    return out / "rig.npz", out / "rig.MAP.yaml"


def main(out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    record, record_map = record_rig(out)
    session = ambid.import_record(record, record_map)                      # step 2
    frf = ambid.estimate_frf(session)                                       # step 3
    model = ambid.fit_model(frf)
    print(f"{session.path}: {frf.frf.shape[0]} lines, fitted order {model.order}")
    for mode in model.modes:
        ci = "" if mode.freq_hz_ci95 is None else \
            f" (95 % CI {mode.freq_hz_ci95[0]:.2f}..{mode.freq_hz_ci95[1]:.2f} Hz)"
        print(f"  mode {mode.freq_hz:8.2f} Hz{ci}, damping {mode.damping:.4f}"
              + ("" if mode.stable else "  (not stable in the diagram)"))
    update = ambid.update_model(frf, ambid.load_rig(), model)               # step 4
    for name, (lo, hi) in zip(update.result.names, update.result.ci95):
        print(f"  updated {name}: {update.parameters[name]:.5g} (95 % CI {lo:.5g}..{hi:.5g})")
    return {"session": session, "frf": frf, "model": model, "update": update}


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="ambid_example_")))
