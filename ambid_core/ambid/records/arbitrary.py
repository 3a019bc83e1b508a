"""An excitation that does not repeat itself (noise, chirps, a PRBS or a multisine started mid-run): its band, its
level and the lines of the local polynomial method, from the record.

:class:`RecordedExcitation` is fed the excitation r in row chunks (memory: one
spectrum segment, flat in the record's length) and keeps its peak, its mean
square and a Welch spectrum (Hann, :data:`SEGMENT` samples, no overlap). Its
:meth:`RecordedExcitation.design` is a 'recorded' design
(:class:`ambid.excitation.design.ExcitationDesign`): one segment of the whole
record from the excitation's first row, whose FRF the local polynomial method
(:mod:`ambid.frf.lpm`) estimates at the centres of its windows in the band
where every input is excited.
"""

from __future__ import annotations

import numpy as np

from ambid.excitation.design import ExcitationDesign
from ambid.frf.lpm import half_width_for, window_centres

from .readers import RecordError

__all__ = ["SEGMENT", "BAND_LEVEL", "LPM_DEGREE", "RecordedExcitation"]

#: samples per segment of the Welch spectrum that finds the band
SEGMENT = 4096
#: an input is excited where its spectrum is within this factor (-20 dB) of its own peak
BAND_LEVEL = 1e-2
#: degree of the local polynomials
LPM_DEGREE = 2


class RecordedExcitation:
    """Fed r (n, Nu) in row chunks from the excitation's first row; its band, level and 'recorded' design.

    Parameters
    ----------
    n_inputs
        Nu.
    """

    def __init__(self, n_inputs: int) -> None:
        self.nu = int(n_inputs)
        self.rows = 0
        self.peak = np.zeros(self.nu)
        self.sum_sq = np.zeros(self.nu)
        self._carry = np.zeros((0, self.nu))
        self._psd = np.zeros((SEGMENT // 2 + 1, self.nu))
        self._segments = 0
        self._win = np.hanning(SEGMENT + 1)[:-1]

    def add(self, r: np.ndarray) -> None:
        """Next rows of the excitation [A]."""
        r = np.asarray(r, dtype=float)
        self.rows += len(r)
        if not len(r):
            return
        self.peak = np.maximum(self.peak, np.abs(r).max(axis=0))
        self.sum_sq += np.sum(r ** 2, axis=0)
        x = np.concatenate([self._carry, r])
        k = len(x) // SEGMENT
        if k:
            seg = x[:k * SEGMENT].reshape(k, SEGMENT, self.nu)
            seg = (seg - seg.mean(axis=1, keepdims=True)) * self._win[None, :, None]
            self._psd += np.sum(np.abs(np.fft.rfft(seg, axis=1)) ** 2, axis=0)
            self._segments += k
        self._carry = x[k * SEGMENT:]

    def spectrum(self) -> np.ndarray:
        """(L/2+1, Nu) mean power per bin of L-sample segments (L = :data:`SEGMENT`, or the whole excitation
        when it is shorter), scaled so that white noise of variance s^2 gives s^2 [A^2]."""
        if self._segments == 0:
            x = self._carry - self._carry.mean(axis=0)
            win = np.hanning(len(x) + 1)[:-1]
            return np.abs(np.fft.rfft(x * win[:, None], axis=0)) ** 2 / max(np.sum(win ** 2), 1e-300)
        return self._psd / (self._segments * np.sum(self._win ** 2))

    def _segment_length(self) -> int:
        return SEGMENT if self._segments else len(self._carry)

    def band(self, fs_hz: float, path: str, names) -> tuple[float, float]:
        """The band where every input's spectrum is within :data:`BAND_LEVEL` of its own peak [Hz]."""
        if self._segment_length() < 64:
            raise RecordError(f"{path}: the excitation lasts {self.rows} rows: too short to find its band; give a "
                              "longer record, or band_hz: and design: in MAP.yaml")
        psd = self.spectrum()[1:]                                          # DC left out
        on = psd >= BAND_LEVEL * psd.max(axis=0, keepdims=True)
        step = fs_hz / self._segment_length()
        lo = np.array([np.flatnonzero(on[:, i])[0] + 1 for i in range(self.nu)]) * step
        hi = np.array([np.flatnonzero(on[:, i])[-1] + 1 for i in range(self.nu)]) * step
        if lo.max() >= hi.min():
            spans = ", ".join(f"{n} {a:g}-{b:g} Hz" for n, a, b in zip(names, lo, hi))
            raise RecordError(f"{path}: the inputs are excited in bands that do not overlap ({spans}); excite every "
                              "input in the band of interest, or give band_hz: in MAP.yaml")
        return float(lo.max()), float(hi.min())

    def design(self, input_names, fs_hz: float, band_hz: tuple[float, float] | None, path: str,
               reason: str) -> ExcitationDesign:
        """The 'recorded' design of the rows fed, in the given band (default :meth:`band`)."""
        names = tuple(input_names)
        band = self.band(fs_hz, path, names) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
        h = half_width_for(LPM_DEGREE, self.nu)
        try:
            lines = window_centres(self.rows, fs_hz, band, h)
        except ValueError:
            need = (2 * h + 1) * fs_hz / (band[1] - band[0])
            raise RecordError(f"{path}: the excitation's {self.rows} rows ({self.rows / fs_hz:.3g} s) hold fewer than "
                              f"{2 * h + 1} bins in the band {band[0]:g}-{band[1]:g} Hz; give a record of at least "
                              f"{need:.3g} s, or a wider band_hz:") from None
        rms = np.sqrt(self.sum_sq / max(self.rows, 1))
        if np.any(rms == 0):
            dead = [n for n, v in zip(names, rms) if v == 0]
            raise RecordError(f"{path}: excitation of {dead} is zero in every row; excite every input the MAP.yaml "
                              "maps, or map only the excited ones")
        # the line amplitude of the whole record in the 2/N scaling, from the spectrum at each line
        step = fs_hz / max(self._segment_length(), 1)
        psd = self.spectrum()
        at = np.clip(np.rint(lines * fs_hz / self.rows / step).astype(int), 0, psd.shape[0] - 1)
        amps = 2.0 * np.sqrt(psd[at].T / self.rows)
        return ExcitationDesign(
            kind="recorded", fs_hz=fs_hz, n_per_period=self.rows, n_periods=1, n_transient_periods=0,
            n_realisations=1, n_experiments=1, input_names=names, excited_lines=lines,
            detection_lines_odd=np.zeros(0, np.int64), detection_lines_even=np.zeros(0, np.int64),
            amplitudes_a=amps, phasors=None, peak_a=self.peak, rms_a=rms, crest_factor=self.peak / rms,
            band_hz=band, seed=None,
            options={"reconstructed": True, "mimo": "as recorded", "estimator": "lpm", "not_periodic": reason,
                     "lpm": {"degree": LPM_DEGREE, "half_width": int(h), "method": "auto"}})
