"""ambid's public API: a recorded session in, its FRF, a parametric model and the updated physical model out.

Everything here is also reachable as ``ambid.<name>`` (``import ambid``). These are the
steps ``ambid identify`` and ``ambid fit`` take after the recording, one call each, with
the same numbers:

==========================  ================================================================
:func:`read_session`        a session MCAP file (``ambid identify``, the recorder, ``ambid import``)
:func:`estimate_frf`        its frequency-response matrix u -> y with noise and total variance
:func:`fit_model`           the common-denominator model, its modes with 95 % intervals
:func:`update_model`        the rig's physical parameters updated to the FRF, with 95 % intervals
:func:`design_excitation`   an excitation experiment (identify's by default)
:func:`import_record`       a rig's own time records (CSV, MAT, NPZ) as a session
:func:`load_rig`            a rig parameter file (or the built-in rig)
==========================  ================================================================
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ambid.excitation.design import ExcitationDesign
from ambid.excitation.spec import DesignSpec
from ambid.fit import FitResult, to_statespace
from ambid.fit.model_update import PhysicalUpdate
from ambid.frf.offline import frf_from_session, session_designs
from ambid.frf.streaming import FrfResult
from ambid.identification.inputs import session_rig
from ambid.identification.model_fit import FrfFit, fit_frf
from ambid.identification.update import update_rig
from ambid.plant.rig import Rig, make_rig
from ambid.plant.rig import load_rig as _load_rig_file
from ambid.records.importer import import_record as _import_record
from ambid.records.mapping import RecordMap
from ambid.recording import NotASessionError, check_session_file, read_metadata
from ambid.statespace import StateSpace

__all__ = ["Session", "Frf", "Mode", "Model", "read_session", "estimate_frf", "fit_model", "update_model",
           "design_excitation", "import_record", "load_rig"]


@dataclass(frozen=True)
class Session:
    """A recorded session: its file, what it says about itself, and its experiments.

    Attributes
    ----------
    path : str
        The MCAP file.
    facts : dict
        The session facts the recorder wrote (rig, plant, controller, excitation, ...).
    experiments : list of dict
        Per excitation experiment, in recording order: ``experiment_id``, ``start_index``,
        ``total_samples`` [samples] and ``design`` (:class:`ambid.excitation.ExcitationDesign`).
    """

    path: str
    facts: dict
    experiments: list[dict]

    @property
    def design(self) -> ExcitationDesign:
        """The last experiment's excitation design."""
        return self.experiments[-1]["design"]

    @property
    def rig(self) -> Rig | None:
        """The rig the session recorded (a simulated one, or the rig file a bridge was given), or None."""
        facts, _ = session_rig(self.path)
        return make_rig(facts) if facts else None


@dataclass(frozen=True)
class Frf:
    """A measured frequency-response matrix and what fitting it needs.

    Attributes
    ----------
    result : ambid.frf.streaming.FrfResult
        The estimate: ``freq_hz`` (L,), ``frf`` (L, Ny, Nu), ``var_noise`` and ``var_total``
        (L, Ny, Nu), ``coherence``, ``sensitivity``, noise and distortion levels, channel names.
    sample_rate_hz : float
        The measurement's sample rate [Hz] (a fitted discrete-time delay of half a sample).
    experiment_id : str
        The experiment it comes from.
    """

    result: FrfResult
    sample_rate_hz: float
    experiment_id: str = ""

    @property
    def freq_hz(self):
        """(L,) excited lines [Hz]."""
        return self.result.freq_hz

    @property
    def frf(self):
        """(L, Ny, Nu) G, u [A] -> y [m]."""
        return self.result.frf


@dataclass(frozen=True)
class Mode:
    """One fitted mode, as ``ambid identify`` and ``ambid fit`` print and record it.

    Attributes
    ----------
    freq_hz : float
        Undamped natural frequency [Hz].
    damping : float
        Damping ratio [-].
    freq_hz_ci95, damping_ci95 : tuple of float or None
        95 % intervals [Hz], [-] (None where the fit gives none).
    stable : bool
        Found again within 1 % at the next lower order fitted (a physical mode, not a spurious pole).
    whirl : str or None
        forward, backward or standing, for a rotor's x/y matrix; else None.
    """

    freq_hz: float
    damping: float
    freq_hz_ci95: tuple[float, float] | None = None
    damping_ci95: tuple[float, float] | None = None
    stable: bool = True
    whirl: str | None = None


@dataclass(frozen=True)
class Model:
    """A common-denominator model fitted to an FRF.

    Attributes
    ----------
    modes : tuple of Mode
        The in-band complex pole pairs, by frequency.
    order : int
        The model order (chosen by the stabilisation-diagram rule unless given).
    statespace : ambid.statespace.StateSpace
        Its continuous-time realisation, u [A] -> y [m] (the half-sample delay apart).
    fit : ambid.fit.FitResult
        Everything the fit knows (poles, residues, chi2/dof, covariance).
    details : ambid.identification.model_fit.FrfFit
        The fit as identify ran it (diagram, weights, interval rows).
    """

    modes: tuple[Mode, ...]
    order: int
    statespace: StateSpace
    fit: FitResult
    details: FrfFit


def read_session(path: str | os.PathLike) -> Session:
    """Read a recorded session.

    Parameters
    ----------
    path : str or PathLike
        A session MCAP file, as ``ambid identify`` (``DIR/session.mcap``), the recorder or
        ``ambid import`` write it.

    Returns
    -------
    Session
        Its facts and its experiments with their designs.

    Raises
    ------
    FileNotFoundError, IsADirectoryError
        No such file, or a folder.
    ambid.recording.NotASessionError
        Not an MCAP file, or one without an excitation experiment.

    Examples
    --------
    >>> import ambid
    >>> s = ambid.read_session(session_path)      # e.g. "identify/session.mcap"
    >>> s.design.kind, s.design.n_experiments
    ('multisine', 4)
    """
    path = os.fspath(path)
    check_session_file(path)
    experiments = session_designs(path)
    if not experiments:
        raise NotASessionError(f"{path} holds no excitation experiment (no excitation/design message)")
    facts = dict(read_metadata(path).get("ambid.session", {}))
    return Session(path, facts, experiments)


def estimate_frf(session: Session | str | os.PathLike, estimator: str = "indirect",
                 experiment_id: str | None = None) -> Frf:
    """Estimate the FRF matrix u -> y of one experiment of a session.

    Parameters
    ----------
    session : Session or path
        From :func:`read_session`, or its file.
    estimator : str
        ``"indirect"`` (closed loop: S_yr S_ur^-1, the default), ``"h1"``, ``"h2"``,
        ``"arithmetic_mean"``, ``"log_mean"`` or ``"eiv"``.
    experiment_id : str, optional
        Which experiment; the last one recorded by default.

    Returns
    -------
    Frf
        The estimate with its noise (period-to-period) and total (realisation-to-realisation)
        variance, as ``ambid identify`` computes it.

    Examples
    --------
    >>> frf = ambid.estimate_frf(s)
    >>> frf.frf.shape                              # lines, outputs y, inputs u
    (34, 4, 4)
    """
    if not isinstance(session, Session):
        session = read_session(session)
    chosen = [e for e in session.experiments if experiment_id in (None, e["experiment_id"])]
    if not chosen:
        known = [e["experiment_id"] for e in session.experiments]
        raise ValueError(f"{session.path} has no experiment {experiment_id!r}; it has {known}")
    result = frf_from_session(session.path, estimator=estimator, experiment_id=experiment_id)
    return Frf(result, float(chosen[-1]["design"].fs_hz), chosen[-1]["experiment_id"])


def fit_model(frf: Frf, order: int | None = None, *, max_order: int = 32, order_penalty: float = 2.0) -> Model:
    """Fit a common-denominator model to an FRF, as ``ambid identify`` and ``ambid fit`` do.

    Parameters
    ----------
    frf : Frf
        From :func:`estimate_frf`.
    order : int, optional
        The model order; by default the smallest information criterion among the orders whose
        in-band modes are positively damped and stable in the stabilisation diagram.
    max_order : int
        Highest order tried.
    order_penalty : float
        Criterion weight per parameter (2: Akaike).

    Returns
    -------
    Model
        ``.modes``: frequency, damping and their 95 % intervals, the very figures identify prints
        and writes to ``summary.json`` (``fit.modes``).

    Examples
    --------
    >>> m = ambid.fit_model(frf)
    >>> [round(mode.freq_hz) for mode in m.modes if mode.stable]
    [177, 310, 927]
    >>> lo, hi = m.modes[0].freq_hz_ci95
    >>> lo < m.modes[0].freq_hz < hi
    True
    """
    mf = fit_frf(frf.result, frf.sample_rate_hz, order, max_order=max_order, order_penalty=order_penalty)
    modes = tuple(Mode(r.freq_hz, r.damping, None if r.interval is None else tuple(r.interval.freq_hz_ci95),
                       None if r.interval is None else tuple(r.interval.damping_ci95), r.stable, r.whirl)
                  for r in mf.mode_rows)
    return Model(modes, mf.order, to_statespace(mf.fit.model), mf.fit, mf)


def update_model(frf: Frf, rig: Rig | str | os.PathLike | None = None, model: Model | None = None, *,
                 start: Mapping[str, float] | None = None, free: Sequence[str] | None = None) -> PhysicalUpdate:
    """Update the rig's physical parameters (ki, ks, bandwidths, bending and support modes, delay) to an FRF.

    Parameters
    ----------
    frf : Frf
        From :func:`estimate_frf`.
    rig : Rig, path or None
        The rig whose analytical model is the start (data-sheet values); a rig file or
        :func:`load_rig`'s result; None: the built-in rig.
    model : Model, optional
        The fitted model (:func:`fit_model`): a mode it shows that the rig lacks starts a support
        mode. Fitted here when not given.
    start : mapping, optional
        Nominal values replacing the rig's (parameter name -> value): the centres of the priors the
        rig's tolerances make (docs/uncertainty.md). The update itself starts from the data.
    free : sequence of str, optional
        Parameters to update; by default those identify updates.

    Returns
    -------
    ambid.fit.model_update.PhysicalUpdate
        ``.parameters`` (every value), ``.result.ci95`` (95 % intervals of the free ones, in
        ``.result.names`` order), ``.to_dict()`` as identify writes it.

    Raises
    ------
    ValueError
        The update cannot be made (the message says why).

    Examples
    --------
    >>> up = ambid.update_model(frf, ambid.load_rig(), m)
    >>> 150 < up.parameters["ki_n_per_a"] < 210      # N/A
    True
    """
    if not isinstance(rig, Rig):
        rig = load_rig(rig)
    details = (model if model is not None else fit_model(frf)).details
    updated = update_rig(rig, frf.result, details, 1.0 / frf.sample_rate_hz, start, free)
    if updated.update is None:
        raise ValueError(f"model updating failed: {updated.error}")
    return updated.update


def design_excitation(fs_hz: float | None = None, speed_rpm: float = 0.0, **terms) -> ExcitationDesign:
    """An excitation experiment in the user's terms; with none given, the one ``ambid identify`` runs.

    Parameters
    ----------
    fs_hz : float, optional
        The plant's sample rate [Hz]; the built-in rig's (10 kHz) by default.
    speed_rpm : float
        Rotor speed [rpm]; > 0 steers a multisine's lines clear of the synchronous harmonics.
    **terms
        Any field of :class:`ambid.excitation.spec.DesignSpec`: ``kind``, ``band_hz``,
        ``resolution_hz``, ``input_names``, ``peak_current_a``, ``n_periods``, ``n_realisations``,
        ``n_transient_periods``, ``grid``, ``phases``, ``mimo``, ``seed``, ...

    Returns
    -------
    ambid.excitation.ExcitationDesign
        Its lines, crest factor, peak and RMS per input, measurement time, and ``samples(offset, n)``.

    Examples
    --------
    >>> d = ambid.design_excitation(band_hz=(20, 400), resolution_hz=20, n_realisations=1, phases="random")
    >>> d.kind, d.n_experiments, round(d.measurement_time_s, 2)
    ('multisine', 4, 1.4)
    """
    spec = replace(DesignSpec(), **terms)
    return spec.build(make_rig().sample_rate_hz if fs_hz is None else fs_hz, speed_rpm)


def import_record(data: str | os.PathLike, record_map: str | os.PathLike | RecordMap,
                  out: str | os.PathLike | None = None) -> Session:
    """A rig's own time records (CSV, MATLAB v5/v7.3, NPZ) as a session, read back.

    Parameters
    ----------
    data : path
        The record: one column per channel (and optionally a time column).
    record_map : path or RecordMap
        The MAP.yaml that says which column is which channel and how to scale it to SI
        (``docs/import.md``).
    out : path, optional
        The session file to write; ``data`` with the suffix ``.mcap`` by default.

    Returns
    -------
    Session
        The session written (:func:`read_session`).

    Raises
    ------
    ambid.records.mapping.RecordError
        One line naming the file, column, row and fix.

    Examples
    --------
    >>> s2 = ambid.import_record(record_path, map_path, out=new_session_path)   # e.g. "rig.npz", "rig.MAP.yaml"
    >>> s2.design.n_realisations, s2.design.n_experiments
    (2, 4)
    """
    out = Path(data).with_suffix(".mcap") if out is None else Path(out)
    _import_record(data, record_map, out)
    return read_session(out)


def load_rig(path: str | os.PathLike | None = None) -> Rig:
    """A rig: every physical parameter of the plant, from a YAML rig file or the built-in rig.

    Parameters
    ----------
    path : path, optional
        A rig file (``rigs/*.yaml``; unknown or out-of-range values are refused with the reason);
        None: the built-in rig (``docs/default_rig.md``).

    Returns
    -------
    ambid.plant.rig.Rig

    Examples
    --------
    >>> rig = ambid.load_rig()
    >>> rig.sample_rate_hz, rig.rotor_mass_kg > 10
    (10000.0, True)
    """
    return make_rig() if path is None else _load_rig_file(path)
