"""The crest-factor phases kept on disk (ambid.disk_cache): a cached design equals a fresh one to the bit,
and any input that changes the result is a new key."""

from __future__ import annotations

import numpy as np
import pytest
from ambid.channels import RADIAL
from ambid.excitation import design_multisine, multisine
from ambid.excitation.spec import DesignSpec


def _design(seed: int = 7, peak: float = 0.4):
    return design_multisine((20.0, 800.0), 20.0, 10_000.0, list(RADIAL.inputs), peak, n_periods=2,
                            n_realisations=2, seed=seed, phases="crest_optimised")


def test_cached_design_equals_the_fresh_one_to_the_bit(tmp_path, monkeypatch):
    monkeypatch.setenv("AMBID_CACHE_DIR", "off")
    fresh = _design()
    monkeypatch.setenv("AMBID_CACHE_DIR", str(tmp_path))
    first = _design()          # computed, then stored
    stored = sorted((tmp_path / "crest_phases").glob("*.npy"))
    assert len(stored) == 2 * 4   # one phase vector per realisation and input

    def not_again(*args):
        raise AssertionError("the phases were optimised again instead of read from the cache")

    monkeypatch.setattr(multisine, "_optimise", not_again)
    cached = _design()
    for d in (first, cached):
        assert d == fresh
        assert np.array_equal(d.phasors, fresh.phasors) and d.phasors.tobytes() == fresh.phasors.tobytes()
        assert np.array_equal(d.samples(0, d.total_samples), fresh.samples(0, fresh.total_samples))
    # the seed is part of the key: another seed is computed (and would call _optimise)
    with pytest.raises(AssertionError, match="optimised again"):
        _design(seed=8)


def test_a_damaged_cache_entry_is_computed_again(tmp_path, monkeypatch):
    monkeypatch.setenv("AMBID_CACHE_DIR", str(tmp_path))
    first = _design()
    for f in (tmp_path / "crest_phases").glob("*.npy"):
        f.write_bytes(b"not an array")
    again = _design()
    assert again == first and again.phasors.tobytes() == first.phasors.tobytes()


def test_unwritable_cache_is_skipped(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    monkeypatch.setenv("AMBID_CACHE_DIR", str(blocker / "below_a_file"))   # cannot be created
    assert _design() == _design()


def test_identify_default_design_through_the_cache(tmp_path, monkeypatch):
    # identify's own experiment (DesignSpec defaults): cached == fresh, the spec's amplitudes unchanged
    spec = DesignSpec()
    monkeypatch.setenv("AMBID_CACHE_DIR", "off")
    fresh = spec.build(10_000.0, 0.0, RADIAL.inputs)
    monkeypatch.setenv("AMBID_CACHE_DIR", str(tmp_path))
    spec.build(10_000.0, 0.0, RADIAL.inputs)
    cached = spec.build(10_000.0, 0.0, RADIAL.inputs)
    assert cached == fresh and cached.phasors.tobytes() == fresh.phasors.tobytes()
    assert np.array_equal(cached.peak_a, fresh.peak_a)
