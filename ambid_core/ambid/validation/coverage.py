"""How honest ambid's intervals are: their empirical coverage over repeated sessions.

One *record* per session (:func:`seed_record`) holds, for every kind of
interval ambid prints, the estimate, the claimed standard deviation or
interval, and the truth the simulated rig knows. :func:`coverage_table`
pools the records of many seeds (different noise and random phases) into
one row per kind:

* ``nominal``: the level the interval claims. A +-2 sigma band of a complex
  FRF value with ``sigma^2 = E|G_hat - G|^2`` is a disc; for a circular
  complex Gaussian error ``P(|e| <= 2 sigma) = 1 - exp(-4) = 0.982``. The
  parameter and mode intervals claim 0.95.
* ``coverage``: the fraction of (seed, item) cases whose interval holds the
  truth, with its Clopper-Pearson 95 % interval (``ci95``, the exact
  binomial interval; for the FRF the lines of one seed are taken as
  independent trials).
* ``std_ratio``: empirical over claimed standard deviation,
  ``sqrt(sum (x_hat - x)^2 / sum sigma_claimed^2)`` over the cases: the
  root-mean-square error (bias included) against the root-mean-square
  claimed sigma; 1 when the claims are right, > 1 when they are too narrow.
  The FRF rows also give ``z_rms``, ``sqrt(mean |e|^2 / sigma^2)``, which
  weighs every line alike (sigma spans decades over the lines).

The FRF truth is the true rig's small-signal model sampled with the
zero-order hold (:func:`ambid.plant.true_rig.true_linear_model`), and the
same model with the magnets' slopes at the excitation level; the updated
parameters' truth is what their intervals claim, the parameters of the rig's
best linear approximation at this excitation level (:func:`with_bla_truth`,
:mod:`ambid.validation.bla_truth`), with the rig's values at rest
(:func:`ambid.fit.model_update.true_parameters`) beside it in ``at_rest``; the
modes' the true rig's poles (:func:`ambid.identification.truth.compare_modes`);
the noise level's the sensor noise through the true closed loop
(:func:`ambid.fit.model_update.closed_loop_noise_std`). A ``pooled`` row
counts every parameter and mode interval of every seed as one case.

The nominal model a seed's update starts from is drawn the way a data sheet
misses the real rig (:func:`draw_nominal_rig`): each toleranced parameter's
nominal value is the truth moved by a draw from its prior, so that over the
seeds the truth lies within each tolerance as often as the tolerance says.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ambid.identification.result import Identification
from ambid.jsonable import to_jsonable
from ambid.plant.rig import Rig
from ambid.plant.tolerances import tolerance_for

__all__ = ["FRF_NOMINAL", "POOLED", "clopper_pearson", "frf_record", "seed_record", "with_bla_truth",
           "coverage_table", "coverage_figure", "draw_nominal_rig", "seed_nominal_rig", "PREDICTED_PEAK", "predicted_peak_row"]

#: P(|e| <= 2 sigma) for a circular complex Gaussian error e with E|e|^2 = sigma^2.
FRF_NOMINAL = float(1 - np.exp(-4.0))
#: the row of :func:`coverage_table` that pools every parameter and mode interval
POOLED = "pooled: parameters and modes"
#: the row of tune's predicted input-sensitivity peak (:func:`predicted_peak_row`)
PREDICTED_PEAK = "tune:predicted_peak"


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) binomial interval of a proportion k / n at ``level``."""
    if n <= 0:
        return float("nan"), float("nan")
    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a, k + 1, n - k))
    return lo, hi


def frf_record(G: np.ndarray, G_true: np.ndarray, variances: Mapping[str, np.ndarray]) -> dict:
    """One session's FRF against the truth, per kind of variance.

    Parameters
    ----------
    G, G_true
        (L, Ny, Nu) measured and true FRF.
    variances
        kind name -> (L, Ny, Nu) claimed variance E|G - G_true|^2.

    Returns
    -------
    kind -> {n, covered (cases with |G - G_true| <= 2 sigma), sum_err2,
    sum_var, sum_z2 (of |G - G_true|^2 / sigma^2)}: sums over the L Ny Nu
    cases with a finite, positive variance.
    """
    e2 = np.abs(np.asarray(G) - np.asarray(G_true)) ** 2
    out = {}
    for kind, v in variances.items():
        v = np.asarray(v, dtype=float)
        ok = np.isfinite(v) & (v > 0)
        out[kind] = dict(n=int(ok.sum()), covered=int(np.sum(e2[ok] <= 4 * v[ok])),
                         sum_err2=float(e2[ok].sum()), sum_var=float(v[ok].sum()),
                         sum_z2=float(np.sum(e2[ok] / v[ok])))
    return out


def _interval_rows(prefix: str, items: Sequence[Mapping[str, Any]]) -> dict:
    out = {}
    for it in items:
        if it.get("std") is None or it.get("true") is None or it.get("ci95") is None:
            continue
        out[f"{prefix}{it['name']}"] = dict(value=float(it["value"]), std=float(it["std"]),
                                            ci95=[float(c) for c in it["ci95"]], true=float(it["true"]),
                                            noise_only=bool(it.get("noise_only", False)),
                                            **({} if it.get("true_at_rest") is None
                                               else dict(true_at_rest=float(it["true_at_rest"]))))
    return out


def seed_record(identification: Identification, G: np.ndarray, truths: Mapping[str, np.ndarray],
                variances: Mapping[str, np.ndarray]) -> dict:
    """Everything one session claims, beside the truth, in a JSON-safe dict.

    Parameters
    ----------
    identification
        ``identify_session``'s result for the session.
    G
        (L, Ny, Nu) measured FRF.
    truths
        truth name -> (L, Ny, Nu) true FRF (e.g. the small-signal
        model and the one at the excitation level).
    variances
        as for :func:`frf_record`.

    Returns
    -------
    dict with ``frf`` (:func:`frf_record`), ``intervals`` (name -> value,
    std, ci95, true, noise_only) for the updated free parameters
    (``parameter:<name>``, with ``true_at_rest``: the rig's value at rest; ``true`` is the
    identification's until :func:`with_bla_truth` sets the BLA's), the total lag
    (``derived:total_lag_s``) and the fitted modes with an
    interval (``mode_freq:<k>``, ``mode_damping:<k>``), ``model`` (the
    update's parameter ``names`` and ``free`` ones: its structure), ``noise``
    (the estimated output noise std per channel) and ``noise_interval``
    (its value, std, ci95 and true closed-loop noise std per channel, or
    None where the session has no truth).
    """
    items = []
    upd = identification.update
    params = (upd.parameters if upd is not None else None) or {}
    for name, row in params.items():
        if row.free:
            items.append(dict(name=f"parameter:{name}", value=row.value, std=row.std, ci95=row.ci95, true=row.true,
                              noise_only=None,
                              true_at_rest=row.true if row.true_small_signal is None else row.true_small_signal))
    lag = None if upd is None else upd.total_lag
    if lag is not None and lag.true is not None:
        items.append(dict(name="derived:total_lag_s", value=lag.value, std=lag.std, ci95=lag.ci95,
                          true=lag.true, noise_only=False, true_at_rest=lag.true))
    for m in identification.modes_vs_true:
        iv = m.interval
        if iv is None:
            continue
        for q, value, std, ci95, true in (("freq_hz", m.freq_hz, iv.freq_hz_std, iv.freq_hz_ci95, m.true_freq_hz),
                                          ("damping", m.damping, iv.damping_std, iv.damping_ci95, m.true_damping)):
            if std is not None:
                items.append(dict(name=f"mode_{q}:{m.true_freq_hz:.0f}Hz", value=value, std=std, ci95=ci95,
                                  true=true, noise_only=iv.noise_only))
    items = to_jsonable(items)   # as the identification's JSON holds them (NaN: none)
    nz = identification.noise.to_json()
    noise = nz["output_noise_std_m"]
    frf = {f"{kind} vs {truth}": row for truth, gt in truths.items()
           for kind, row in frf_record(G, gt, variances).items()}
    noise_interval = None
    if all(nz[k] is not None for k in ("output_noise_std_sd_m", "output_noise_std_ci95_m",
                                      "true_output_noise_std_m")):
        noise_interval = dict(value=[float(x) for x in noise], std=[float(x) for x in nz["output_noise_std_sd_m"]],
                              ci95=[[float(c) for c in ci] for ci in nz["output_noise_std_ci95_m"]],
                              true=[float(x) for x in nz["true_output_noise_std_m"]])
    model = None
    if params:
        model = dict(names=sorted(params), free=list(upd.free or []))
    return dict(frf=frf, intervals=_interval_rows("", items), model=model,
                noise=None if noise is None else [float(x) for x in noise], noise_interval=noise_interval)


def with_bla_truth(record: Mapping[str, Any], bla: Mapping[str, float]) -> dict:
    """``record`` with each updated parameter's and the total lag's truth set to what the interval claims:
    the parameters of the rig's best linear approximation at this excitation level, ``bla``
    (:func:`ambid.validation.bla_truth.bla_parameters`: name -> value, ``total_lag_s``). The rig's value at
    rest stays in ``true_at_rest``; a parameter ``bla`` lacks keeps its truth."""
    out = dict(record)
    intervals = {}
    for name, row in record["intervals"].items():
        kind, _, key = name.partition(":")
        key = "total_lag_s" if name == "derived:total_lag_s" else key
        if kind in ("parameter", "derived") and key in bla:
            row = {**row, "true": float(bla[key]), "bla": True}
        intervals[name] = row
    out["intervals"] = intervals
    return out


def _row(nominal: float, covered: int, n: int, err2: float, var: float, **extra) -> dict:
    lo, hi = clopper_pearson(covered, n)
    return dict(nominal=nominal, coverage=covered / n if n else float("nan"), ci95=[lo, hi], covered=covered,
                n=n, std_ratio=float(np.sqrt(err2 / var)) if var > 0 else float("nan"), **extra)


def coverage_table(records: Sequence[Mapping[str, Any]]) -> dict:
    """Pool the records of many seeds into one row per kind of interval (module docstring).

    Returns
    -------
    kind -> {nominal, coverage, ci95 [lo, hi], covered, n, std_ratio, ...}:
    ``frf:<variance kind>`` for the FRF bands, ``<item name>`` for each
    parameter and mode interval (with bias and scatter relative to the
    claimed std), ``noise_std (outputs pooled)`` for the noise level's
    interval (each seed's outputs are cases) and ``noise_std`` for its
    scatter over the seeds.
    """
    table: dict[str, dict] = {}
    kinds = sorted({k for r in records for k in r["frf"]})
    for kind in kinds:
        rows = [r["frf"][kind] for r in records if kind in r["frf"]]
        n = sum(x["n"] for x in rows)
        # sigma spans decades over the lines and entries: the ratio of sums weighs the few largest, the
        # RMS of the normalised errors every line alike (a variance of nu degrees of freedom: sqrt(nu / (nu - 2)))
        z = ({} if not n or any("sum_z2" not in x for x in rows)
             else dict(z_rms=float(np.sqrt(sum(x["sum_z2"] for x in rows) / n))))
        table[f"frf:{kind}"] = _row(FRF_NOMINAL, sum(x["covered"] for x in rows), n,
                                    sum(x["sum_err2"] for x in rows), sum(x["sum_var"] for x in rows),
                                    claim="|G - G_true| <= 2 sigma at each excited line and entry", **z)
    names = sorted({k for r in records for k in r["intervals"]})
    for name in names:
        rows = [r["intervals"][name] for r in records if name in r["intervals"]]
        v = np.array([x["value"] for x in rows])
        t = np.array([x["true"] for x in rows])
        s = np.array([x["std"] for x in rows])
        cov = int(sum(x["ci95"][0] <= x["true"] <= x["ci95"][1] for x in rows))
        rms_s = float(np.sqrt(np.mean(s**2)))
        extra = {}
        if all("noise_free" in x for x in rows):
            # the noise-free twins' estimates: what the excitation alone does (validate's run_seed)
            e0 = np.array([x["noise_free"] for x in rows]) - t
            extra = dict(noise_free_bias_over_std=float(np.mean(e0) / rms_s),
                         noise_free_rms_over_std=float(np.sqrt(np.mean(e0**2)) / rms_s))
        if all("true_at_rest" in x for x in rows):
            # the rig's values at rest: how far the nonlinearity moves what the interval claims
            t0 = np.array([x["true_at_rest"] for x in rows])
            extra.update(at_rest=dict(true=float(np.mean(t0)),
                                      coverage=float(np.mean([x["ci95"][0] <= a <= x["ci95"][1]
                                                              for x, a in zip(rows, t0)])),
                                      std_ratio=float(np.sqrt(np.sum((v - t0) ** 2) / np.sum(s**2))),
                                      shift_over_std=float(np.mean(t - t0) / rms_s)))
        table[name] = _row(0.95, cov, len(rows), float(np.sum((v - t) ** 2)), float(np.sum(s**2)),
                           true=float(np.mean(t)), bias_over_std=float(np.mean(v - t) / rms_s),
                           scatter_over_std=float(np.std(v, ddof=1) / rms_s) if len(v) > 1 else float("nan"),
                           noise_only=bool(rows[0]["noise_only"]),
                           claim="95 % interval holds the parameter of the rig's best linear approximation at this "
                                 "excitation level (at_rest: against the rig at rest)" if all(x.get("bla") for x in rows)
                           else "95 % interval holds the truth", **extra)
    # the derived total lag is its own row, not a case here: it is a sum of three parameters already counted
    cases = [x for r in records for k, x in r["intervals"].items()
             if k.split(":")[0] in ("parameter", "mode_freq_hz", "mode_damping")]
    if cases:
        z = np.array([(x["value"] - x["true"]) / x["std"] for x in cases])
        covered = int(sum(x["ci95"][0] <= x["true"] <= x["ci95"][1] for x in cases))
        lo, hi = clopper_pearson(covered, len(cases))
        # the same cases against the rig at rest (a mode has no other truth than its own)
        t0 = np.array([x.get("true_at_rest", x["true"]) for x in cases])
        z0 = np.array([(x["value"] - a) / x["std"] for x, a in zip(cases, t0)])
        at_rest = dict(coverage=float(np.mean([x["ci95"][0] <= a <= x["ci95"][1] for x, a in zip(cases, t0)])),
                       std_ratio=float(np.sqrt(np.mean(z0**2))))
        table[POOLED] = dict(nominal=0.95, coverage=covered / len(cases), ci95=[lo, hi], covered=covered,
                             n=len(cases), std_ratio=float(np.sqrt(np.mean(z**2))), noise_only=False,
                             at_rest=at_rest,
                             claim="every parameter and mode interval of every seed, one case each; std_ratio "
                                   "is the RMS of error / claimed std")
    noise_iv = [r["noise_interval"] for r in records if r.get("noise_interval")]
    if noise_iv:
        # the outputs of all seeds pooled: one claim, the same formula for each sensor
        v, s, t = (np.concatenate([x[k] for x in noise_iv]) for k in ("value", "std", "true"))
        ci = np.concatenate([np.asarray(x["ci95"], dtype=float).reshape(-1, 2) for x in noise_iv])
        ok = np.isfinite(s) & np.isfinite(t) & np.all(np.isfinite(ci), axis=1)
        v, s, t, ci = v[ok], s[ok], t[ok], ci[ok]
        if v.size:
            rms_s = float(np.sqrt(np.mean(s**2)))
            table["noise_std (outputs pooled)"] = _row(
                0.95, int(np.sum((ci[:, 0] <= t) & (t <= ci[:, 1]))), int(v.size), float(np.sum((v - t) ** 2)),
                float(np.sum(s**2)), bias_over_std=float(np.mean(v - t) / rms_s), noise_only=True,
                claim="95 % interval of each output's noise std holds the true closed-loop noise std")
    noise = [r["noise"] for r in records if r.get("noise") is not None]
    if noise:
        x = np.array(noise)
        table["noise_std"] = dict(nominal=None, coverage=None, n=int(x.shape[0]), mean_m=x.mean(axis=0).tolist(),
                                  relative_scatter=float(np.mean(x.std(axis=0, ddof=1) / x.mean(axis=0)))
                                  if x.shape[0] > 1 else None,
                                  claim="the estimate's scatter over the seeds")
    return table


def predicted_peak_row(cases: Sequence[Mapping[str, Any]]) -> dict | None:
    """The coverage of tune's predicted peak over commissioning cases, one case each.

    Parameters
    ----------
    cases
        each {predicted: {value, ci95: [lo, hi]}, measured}: ``ambid tune``'s ``predicted_peak`` and the
        headline input-sensitivity peak [-] the verifying identification measured (what the prediction
        claims to hold); cases without a measurement are left out.

    Returns
    -------
    :func:`coverage_table`'s row (nominal 0.95, coverage with its Clopper-Pearson interval, std_ratio taking
    the half width over 1.96 as the claimed std), or None without a case.
    """
    rows = [c for c in cases if c.get("measured") is not None and c.get("predicted")]
    if not rows:
        return None
    lo, hi = (np.array([c["predicted"]["ci95"][i] for c in rows], dtype=float) for i in (0, 1))
    v = np.array([c["predicted"]["value"] for c in rows], dtype=float)
    m = np.array([c["measured"] for c in rows], dtype=float)
    s = (hi - lo) / (2 * 1.959964)
    return _row(0.95, int(np.sum((lo <= m) & (m <= hi))), len(rows), float(np.sum((v - m) ** 2)),
                float(np.sum(s**2)), noise_only=False, bias_over_std=float(np.mean(v - m) / np.sqrt(np.mean(s**2))),
                claim="tune's 95 % interval of the predicted peak holds the verifying identification's measured "
                      "headline peak (its own seed's, rig drawn from the tolerances)")


def coverage_figure(table: Mapping[str, Mapping[str, Any]], path: str | Path | None = None):
    """Empirical coverage with its binomial interval beside the nominal level, and the std ratio, per kind."""
    from matplotlib.figure import Figure  # optional (ambid[report]): only the figure needs it

    rows = [(k, r) for k, r in table.items() if r.get("coverage") is not None]
    fig = Figure(figsize=(10, 0.32 * len(rows) + 1.6))
    ax1, ax2 = fig.subplots(1, 2, sharey=True, gridspec_kw=dict(width_ratios=[3, 2]))
    y = np.arange(len(rows))
    for i, (k, r) in enumerate(rows):
        lo, hi = r["ci95"]
        ax1.plot([lo, hi], [i, i], color="0.4", lw=2)
        ax1.plot(r["coverage"], i, "o", color="C3" if r["ci95"][1] < r["nominal"] else "C0")
        ax1.plot(r["nominal"], i, "|", color="k", ms=12)
        ax2.plot(r["std_ratio"], i, "o", color="C3" if not 0.7 <= r["std_ratio"] <= 1.4 else "C0")
    ax1.set_yticks(y, [k for k, _ in rows], fontsize=7)
    ax1.set_xlabel("coverage (dot), Clopper-Pearson 95 % (bar), nominal (|)")
    ax1.set_xlim(-0.02, 1.02)
    ax2.axvspan(0.7, 1.4, color="C2", alpha=0.15)
    ax2.axvline(1.0, color="k", lw=0.8)
    ax2.set_xscale("log")
    ax2.set_xlabel("empirical / claimed std")
    ax1.invert_yaxis()
    ax1.grid(alpha=0.3)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def draw_nominal_rig(rig: Rig, rng: np.random.Generator) -> tuple[dict[str, Any], dict[str, Any]]:
    """A nominal rig as a data sheet of the true rig ``rig`` might give it, drawn from the tolerances.

    Each toleranced parameter of the updating model that a rig file states
    (ki and ks through the air gap and pole area, the amplifier bandwidth
    through the dc link voltage, the sensor bandwidth, the bending modes through
    Young's modulus, the modal damping, the delay's range) is the true value
    moved by one draw from its prior (:mod:`ambid.plant.tolerances`: normal in
    the value or in its logarithm, the tolerance a 95 % interval): over many
    draws the truth lies inside each tolerance 95 % of the time, as a data
    sheet claims. The ratio of the bearings' ks and the support mode have no
    data sheet and are not drawn.

    Parameters
    ----------
    rig
        the true (simulated) rig, with its tolerances.
    rng
        the random generator (seed it per session).

    Returns
    -------
    (overrides, drawn): the rig-file mapping of the nominal rig (``rig``'s
    values with the drawn ones and a ``tolerances`` mapping holding the drawn
    delay range), and each drawn parameter's nominal value, true value and
    its draw in prior standard deviations (name -> {nominal, true, z}).
    """
    from ambid.fit.model_update import nominal_update_parameters, rig_values_for, true_parameters

    truth = true_parameters(rig)
    drawn: dict[str, Any] = {}

    def draw(name: str) -> float:
        tol = tolerance_for(name, rig.tolerances)
        t = float(truth[name])
        centre, sd, log = tol.centre_and_sd(t, rig.dt)
        z = float(rng.standard_normal())
        if tol.kind == "range":
            centre = t                       # the range is placed around the truth, then moved
        value = centre * np.exp(sd * z) if log else centre + sd * z
        drawn[name] = dict(nominal=float(value), true=t, z=z)
        return float(value)

    names = ["ki_n_per_a", "ks_n_per_m", "amplifier_bandwidth_hz", "sensor_bandwidth_hz"]
    if "bending_freq_hz" in nominal_update_parameters(rig):
        names += ["bending_freq_hz", "bending_damping_ratio"]
    targets = {name: draw(name) for name in names + ["delay_s"]}   # in this order: the seeds' draws
    over: dict[str, Any] = dict(rig_values_for(rig, targets))
    tol = tolerance_for("delay_s", rig.tolerances)
    delay = targets["delay_s"]
    tolerances = {k: t.to_text() for k, t in rig.tolerances.items()}
    if tol.kind == "range":
        scale = rig.dt if tol.in_samples else 1.0
        half = 0.5 * (tol.high - tol.low) * scale
        tolerances["delay_s"] = f"{delay - half:.9g}..{delay + half:.9g}"
    base = {k: val for k, val in rig.to_dict().items() if k not in over}
    return {**base, **over, "tolerances": tolerances}, drawn


def seed_nominal_rig(rig: Rig, seed: int, out: Path) -> tuple[Path, dict[str, Any]]:
    """The nominal model a validate seed's update starts from, the user's: the simulated ``rig`` missed by a
    draw from its tolerances (:func:`draw_nominal_rig`, never the truth), written to ``out/nominal_rig.yaml``
    (``out`` created); its path and the draw."""
    import yaml

    out.mkdir(parents=True, exist_ok=True)
    nominal, drawn = draw_nominal_rig(rig, np.random.default_rng([seed, 26]))
    path = out / "nominal_rig.yaml"
    path.write_text(yaml.safe_dump(to_jsonable(nominal), sort_keys=False))
    return path, drawn
