"""``ambid validate`` end to end on two seeds under a chosen controller, on its local Dask cluster: the sessions
and their noise-free twins run, each seed's update starts from a nominal rig drawn from the tolerances (recorded
per seed, never the truth), each seed's identification says which controller ran, the coverage table covers
the interval kinds, and a second run reuses both seeds."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _validate(out: Path, env: dict) -> subprocess.CompletedProcess:
    # its sessions' domains 215..222: the local campaign of tests/docs/test_dask_cluster.py takes 223..230 (the
    # two may run at once under pytest-xdist)
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", "validate", "--seeds", "2", "--controller", "lqg",
                           "--no-figure", "--domain-base", "215", "--out", str(out)], env=env, cwd=REPO, capture_output=True, text=True,
                          timeout=600)


def test_validate_runs_seeds_under_the_chosen_controller_and_reuses_them(ros_env, tmp_path):
    out = tmp_path / "v"
    proc = _validate(out, ros_env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads((out / "coverage.json").read_text())
    assert result["n_seeds"] == 2 and result["seeds"] == [1, 2]
    kinds = result["kinds"]
    claimed = {name: k for name, k in kinds.items() if k.get("nominal") is not None}
    assert {"parameter:ki_n_per_a", "parameter:ks_n_per_m", "mode_freq_hz:310Hz"} <= set(claimed)
    assert any(name.startswith("frf:printed band") for name in claimed)
    assert all(0.0 <= k["coverage"] <= 1.0 and k["n"] >= 2 for k in claimed.values())
    # the noise-only band against each seed's noise-free twin (same grid and phases, no sensor noise): the
    # difference is the noise alone, which that band claims (its variance has 2 M (P - 1) = 18 real degrees
    # of freedom per entry: rms |e| / sigma ~ 1.06)
    twin = kinds["frf:noise only vs noise-free twin"]
    assert twin["n"] > 2000 and twin["coverage"] > 0.93 and 0.85 < twin["z_rms"] < 1.3
    assert "noise_free_rms_over_std" in kinds["parameter:ki_n_per_a"]
    assert (out / "seeds" / "seed_001" / "noise_free" / "frf.npz").is_file()
    assert kinds["pooled: parameters and modes"]["n"] >= 2 * 10
    # the parameters measured against the BLA's, each seed's magnets' slopes at its own excitation (whose
    # mean over the seeds is the pooled estimand's), the rig at rest beside them
    bla = result["bla_parameters"][0]
    assert bla["seeds"] == [1, 2] and set(bla["per_seed"]) == {"1", "2"}
    for k in ("ki_n_per_a", "ks_n_per_m", "ks_b_over_a"):
        own = [bla["per_seed"][s][k] for s in ("1", "2")]
        assert own[0] != own[1] and sum(own) / 2 == pytest.approx(bla["parameters"][k], rel=1e-12)
    assert "at_rest" in kinds["parameter:ki_n_per_a"] and "best linear" in kinds["parameter:ki_n_per_a"]["claim"]
    for seed in (1, 2):
        summary = json.loads((out / "seeds" / f"seed_{seed:03d}" / "identification.json").read_text())
        assert summary["controller"]["kind"] == "lqg"
        # the update's nominal model is the seed's drawn one, and it is not the truth
        drawn = result["nominal_models"][str(seed)]
        assert (out / "seeds" / f"seed_{seed:03d}" / "nominal_rig.yaml").is_file()
        params = summary["update"]["parameters"]
        for name in ("ki_n_per_a", "sensor_bandwidth_hz", "bending_damping_ratio"):
            assert params[name]["nominal"] == pytest.approx(drawn[name]["nominal"], rel=1e-6)
            assert drawn[name]["nominal"] != pytest.approx(drawn[name]["true"], rel=1e-6)
    again = _validate(out, ros_env)
    assert again.returncode == 0 and "(2 reused)" in again.stdout
