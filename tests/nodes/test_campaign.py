"""``ambid campaign`` on the spinning rig: the first bending mode's forward and backward whirl identified
within 0.5 % of the true rig's with the right direction; a campaign continued in its folder runs only the
speeds it lacks; other settings in the same folder are refused."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _campaign(env, out, *speeds, extra=()):
    # its sessions' domains 223..230: test_validate_command's are 215..222 (the two may run at once)
    return subprocess.run([sys.executable, "-m", "ambid_cli.cli", "campaign", "--speeds-rpm", *speeds,
                           "--domain-base", "223",
                           "--rig", str(REPO / "rigs" / "spinning.yaml"), "--out", str(out), "--realisations", "1",
                           "--no-progress", *(extra or ("--resolution", "10"))],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=300)


def test_campaign_identifies_the_whirl_and_continues_where_it_stopped(ros_env, tmp_path):
    out = tmp_path / "campaign"
    proc = _campaign(ros_env, out, "12000")
    assert proc.returncode == 0, proc.stderr[-2000:]
    mcap_12k = out / "rpm_12000" / "session.mcap"
    stamp = mcap_12k.stat().st_mtime_ns
    # continued with one more speed: 12000 rpm is kept as it was, 0 rpm runs
    proc = _campaign(ros_env, out, "0", "12000")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "12000 rpm: done before, kept" in proc.stderr and mcap_12k.stat().st_mtime_ns == stamp
    camp = json.loads((out / "campbell.json").read_text())
    assert [r["speed_rpm"] for r in camp["speeds"]] == [0.0, 12000.0]
    still, spin = (r["first_bending"] for r in camp["speeds"])
    assert still["true"]["whirl"] == still["identified"]["whirl"] == "standing"
    assert spin["true"]["whirl"] == spin["identified"]["whirl"] == "split"
    for fb in (still, spin):
        assert abs(fb["backward_error"]) < 0.005 and abs(fb["forward_error"]) < 0.005
    # the true split at 12,000 rpm is real: backward below forward by several Hz
    assert spin["true"]["forward_hz"] - spin["true"]["backward_hz"] > 5.0
    assert spin["identified"]["forward_hz"] - spin["identified"]["backward_hz"] > 5.0
    assert camp["first_bending_whirl_right"] is True and camp["first_bending_max_error"] < 0.005
    # every identified first-bending frequency carries identify's 95 % interval, and the campaign counts how
    # often those hold the true rig's (2 speeds x 2 whirls)
    for fb in (still, spin):
        for side in ("backward", "forward"):
            lo, hi = fb["identified"][f"{side}_hz_ci95"]
            assert lo < fb["identified"][f"{side}_hz"] < hi and fb[f"{side}_covered"] in (True, False)
    held, n = camp["first_bending_ci_covered"]
    assert n == 4 and f"hold the true frequency {held} of 4 times" in proc.stdout
    # the critical speeds lie where the predicted branches cross 1X
    for c in camp["critical_speeds"]:
        assert abs(c["freq_hz"] - c["speed_rpm"] / 60.0) < 1e-9
    assert (out / "report" / "campbell.png").stat().st_size > 10_000
    assert "| 12000 |" in proc.stdout
    # the same folder with other settings is refused, nothing run
    proc = _campaign(ros_env, out, "0", extra=("--resolution", "20"))
    assert proc.returncode == 2 and "other settings" in proc.stderr
