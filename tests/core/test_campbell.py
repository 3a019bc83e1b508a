"""The Campbell diagram's pieces: a model's modes with their whirl, the predicted branches, the critical
speeds where a branch crosses 1X, and the first bending mode picked out of a list of modes."""

import numpy as np
import pytest
from ambid.plant.rig import make_rig
from ambid.plant.true_rig import true_linear_model
from ambid.identification.campbell import critical_speeds, first_bending, model_modes, predicted_branches

BAND = (100.0, 1000.0)


def test_model_modes_are_standing_at_standstill_and_split_at_speed():
    still = model_modes(true_linear_model(make_rig()), BAND)
    bending = [m for m in still if 290 < m["freq_hz"] < 330]
    assert len(bending) == 1 and bending[0]["whirl"] == "standing"  # the x and y modes merged
    assert bending[0]["forward_share"] == pytest.approx(0.5, abs=0.02)
    spin = model_modes(true_linear_model(make_rig({"rotor_speed_rpm": 12_000.0})), BAND)
    pair = [m for m in spin if 290 < m["freq_hz"] < 330]
    assert [m["whirl"] for m in pair] == ["backward", "forward"]
    assert pair[0]["forward_share"] < 0.05 and pair[1]["forward_share"] > 0.95


def test_predicted_branches_follow_the_gyroscopic_split_and_cross_1x_where_the_model_says():
    rig = make_rig()
    rpm = np.linspace(0.0, 24_000.0, 13)
    br = predicted_branches(rig, rpm, BAND)
    fw, bw = br["mode 1 forward"], br["mode 1 backward"]
    assert fw[0] == pytest.approx(bw[0], rel=1e-6)  # standstill: one standing mode starts both
    assert np.all(np.diff(fw) > 0) and np.all(np.diff(bw) < 0)
    crit = {c["label"]: c for c in critical_speeds(rpm, br)}
    # the crossing of the forward branch: f(rpm) = rpm / 60, checked on the analytical model itself
    from ambid.plant.analytical import analytical_model
    r = crit["mode 1 forward"]["speed_rpm"]
    f_at = [m["freq_hz"] for m in model_modes(analytical_model(make_rig({"rotor_speed_rpm": r})), BAND)
            if m["whirl"] == "forward"][0]
    assert f_at == pytest.approx(r / 60.0, rel=2e-3)  # linear interpolation between grid speeds
    assert crit["mode 1 backward"]["speed_rpm"] < r


def test_critical_speeds_of_straight_branches_by_hand():
    rpm = np.array([0.0, 10_000.0, 20_000.0])
    br = {"a forward": np.array([300.0, 310.0, 320.0]), "b backward": np.array([np.nan, 500.0, 490.0])}
    crit = critical_speeds(rpm, br)
    # 300 + rpm / 1000 = rpm / 60  ->  rpm = 300 / (1/60 - 1/1000)
    assert len(crit) == 1 and crit[0]["speed_rpm"] == pytest.approx(300 / (1 / 60 - 1 / 1000))


def test_first_bending_takes_a_standing_mode_for_both_whirls():
    modes = [dict(freq_hz=177.0, damping=0.02, whirl="standing", forward_share=0.5),
             dict(freq_hz=310.2, damping=0.005, whirl="standing", forward_share=0.51)]
    fb = first_bending(modes, 310.0)
    assert fb["backward_hz"] == fb["forward_hz"] == 310.2 and fb["whirl"] == "standing"
    modes += [dict(freq_hz=306.0, damping=0.005, whirl="backward", forward_share=0.01),
              dict(freq_hz=315.0, damping=0.005, whirl="forward", forward_share=0.99)]
    fb = first_bending(modes, 310.0)
    assert (fb["backward_hz"], fb["forward_hz"], fb["whirl"]) == (306.0, 315.0, "split")
    assert first_bending(modes[:1], 310.0)["forward_hz"] is None
    # a mode's 95 % interval travels with it
    modes[3]["freq_hz_ci95"] = [314.5, 315.5]
    fb = first_bending(modes, 310.0)
    assert fb["forward_hz_ci95"] == [314.5, 315.5] and fb["backward_hz_ci95"] is None
