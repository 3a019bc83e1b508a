"""Linear state-space models: one small dataclass and the operations on it.

Every model that travels between parts of ambid (rig models, controllers,
fitted models) is a :class:`StateSpace`; its ``dt`` tells continuous (0) from
discrete (sample period in s).
"""

from __future__ import annotations

import warnings

from dataclasses import dataclass, field

import numpy as np
from scipy import linalg


def zoh_blocks(a: np.ndarray, b: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(exp(A t), int_0^t exp(A s) ds B) via one augmented matrix exponential (A (n, n), B (n, m), t [s])."""
    n, m = b.shape
    aug = np.zeros((n + m, n + m))
    aug[:n, :n], aug[:n, n:] = a, b
    e = linalg.expm(aug * t)
    return e[:n, :n], e[:n, n:]


def discretise(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, dt: float, method: str = "zoh"
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The discrete (A, B, C, D) of a continuous model with sample period ``dt`` [s]: zero-order hold or
    bilinear (Tustin), with scipy.signal.cont2discrete's arithmetic, so its matrices to the bit. Here, not
    from scipy.signal: that package imports scipy.stats, ~0.5 s of CPU in every process that builds a
    controller (each controller node of a session).

    Examples
    --------
    >>> import numpy as np
    >>> ad, bd, cd, dd = discretise(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.zeros((1, 1)),
    ...                             0.1, "bilinear")
    >>> np.round(ad, 6)                    # Tustin's pole: (1 - 0.05) / (1 + 0.05)
    array([[0.904762]])
    """
    n = a.shape[0]
    if method in ("bilinear", "tustin"):
        ima = np.eye(n) - 0.5 * dt * a
        ad = linalg.solve(ima, np.eye(n) + 0.5 * dt * a)
        bd = linalg.solve(ima, dt * b)
        cd = linalg.solve(ima.transpose(), c.transpose()).transpose()
        return ad, bd, cd, d + 0.5 * np.dot(c, bd)
    if method == "zoh":
        return (*zoh_blocks(a, b, dt), c, d)
    raise ValueError(f"discretise: method {method!r} is not zoh or bilinear")


@dataclass(frozen=True)
class StateSpace:
    """x' = A x + B u, y = C x + D u (dt = 0) or x[k+1] = A x[k] + B u[k] (dt > 0).

    Attributes
    ----------
    a
        (n, n) state matrix.
    b
        (n, m) input matrix.
    c
        (p, n) output matrix.
    d
        (p, m) feed-through matrix.
    dt
        sample period [s]; 0 for continuous time.
    input_names, output_names
        channel names (len m and p).
    input_units, output_units
        SI units of the channels (e.g. "A", "m").

    Examples
    --------
    A first-order lag 2 / (s + 1): its pole, its static gain and its gain at the corner frequency.

    >>> import numpy as np
    >>> lag = StateSpace(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.array([[0.0]]))
    >>> lag.n_states, lag.n_inputs, lag.n_outputs
    (1, 1, 1)
    >>> lag.poles(), lag.is_stable()
    (array([-1.]), True)
    >>> g = lag.freqresp(np.array([0.0, 1.0 / (2 * np.pi)]))   # (L, Ny, Nu)
    >>> g.shape
    (2, 1, 1)
    >>> np.round(np.abs(g[:, 0, 0]), 4)
    array([2.    , 1.4142])
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    dt: float = 0.0
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())
    input_units: tuple[str, ...] = field(default=())
    output_units: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        a, b, c, d = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (self.a, self.b, self.c, self.d))
        n = a.shape[0]
        if a.shape != (n, n):
            raise ValueError(f"StateSpace: A must be square, got shape {a.shape}")
        if n == 0:
            b = b.reshape(0, d.shape[1])
            c = c.reshape(d.shape[0], 0)
        if b.shape[0] != n or c.shape[1] != n or d.shape != (c.shape[0], b.shape[1]):
            raise ValueError(
                f"StateSpace: inconsistent shapes A{a.shape} B{b.shape} C{c.shape} D{d.shape}; "
                "need A (n,n), B (n,m), C (p,n), D (p,m)")
        for name, m in zip("abcd", (a, b, c, d)):
            if not np.all(np.isfinite(m)):
                raise ValueError(f"StateSpace: matrix {name.upper()} contains NaN or Inf")
        if not np.isfinite(self.dt) or self.dt < 0:
            raise ValueError(f"StateSpace: dt must be >= 0 (0 = continuous), got {self.dt}")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "d", d)
        for attr, size in (("input_names", b.shape[1]), ("output_names", c.shape[0]),
                           ("input_units", b.shape[1]), ("output_units", c.shape[0])):
            names = tuple(getattr(self, attr))
            if names and len(names) != size:
                raise ValueError(f"StateSpace: {attr} has {len(names)} entries for {size} channels")
            object.__setattr__(self, attr, names)

    @property
    def n_states(self) -> int:
        return self.a.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.b.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.c.shape[0]

    def poles(self) -> np.ndarray:
        """Eigenvalues of A (s-plane for dt = 0, z-plane for dt > 0), shape (n,)."""
        return np.linalg.eigvals(self.a)

    def is_stable(self, margin: float = 0.0) -> bool:
        """All poles strictly inside the stability region (by ``margin``)."""
        p = self.poles()
        if self.dt > 0:
            return bool(np.all(np.abs(p) < 1.0 - margin))
        return bool(np.all(p.real < -margin))

    def unstable_poles(self) -> np.ndarray:
        """The poles outside the stability region, shape (k,)."""
        p = self.poles()
        return p[np.abs(p) >= 1.0] if self.dt > 0 else p[p.real >= 0]

    def freqresp(self, freq_hz: np.ndarray) -> np.ndarray:
        """Frequency response at ``freq_hz`` (L,), shape (L, p, m).

        Continuous: G(j 2 pi f). Discrete: G(exp(j 2 pi f dt)).
        Evaluated in a Hessenberg basis, every line in one batched solve (scipy's, the same LAPACK
        factorisation per line as a loop over the lines, so the same numbers; ~5x faster for 10^4 lines
        of a 16-state controller: the loop was mostly Python overhead).
        """
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        s = np.exp(2j * np.pi * f * self.dt) if self.dt > 0 else 2j * np.pi * f
        if self.n_states == 0:
            return np.broadcast_to(self.d, (f.size,) + self.d.shape).astype(complex)
        h, q = linalg.hessenberg(self.a, calc_q=True)
        bq = q.T @ self.b
        cq = self.c @ q
        eye = np.eye(self.n_states)
        out = np.empty((f.size, self.n_outputs, self.n_inputs), dtype=complex)
        step = max(1, (1 << 22) // (self.n_states * self.n_states))   # lines per solve: ~64 MB of matrices
        ill = 0
        for k in range(0, f.size, step):
            sk = s[k:k + step, None, None]
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", linalg.LinAlgWarning)
                x = linalg.solve(sk * eye - h, np.broadcast_to(bq, (sk.shape[0],) + bq.shape))
            ill += sum(str(w.message).count("slice") for w in caught if issubclass(w.category, linalg.LinAlgWarning))
            out[k:k + step] = cq @ x + self.d
        if ill:   # one line, where scipy names every slice
            warnings.warn(f"freqresp: (zI - A) is ill-conditioned at {ill} of {f.size} lines (a pole on or "
                          "next to them)", linalg.LinAlgWarning, stacklevel=2)
        return out

    def to_discrete(self, dt: float, method: str = "zoh") -> "StateSpace":
        """Discretise a continuous model with sample period ``dt`` [s] (zoh or bilinear).

        Examples
        --------
        >>> import numpy as np
        >>> lag = StateSpace(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.array([[0.0]]))
        >>> z = lag.to_discrete(0.1)          # zero-order hold at 10 Hz: the pole moves to exp(-0.1)
        >>> np.round(z.poles(), 6), z.dt
        (array([0.904837]), 0.1)
        """
        if self.dt > 0:
            raise ValueError("to_discrete: the model is already discrete")
        ad, bd, cd, dd = discretise(self.a, self.b, self.c, self.d, dt, method)
        return self._replace(a=ad, b=bd, c=cd, d=dd, dt=dt)

    def _replace(self, **changes) -> "StateSpace":
        fields = dict(a=self.a, b=self.b, c=self.c, d=self.d, dt=self.dt,
                      input_names=self.input_names, output_names=self.output_names,
                      input_units=self.input_units, output_units=self.output_units)
        fields.update(changes)
        return StateSpace(**fields)

    def to_dict(self) -> dict:
        """JSON-safe dict (lists), inverse of :func:`statespace_from_dict`."""
        return dict(a=self.a.tolist(), b=self.b.tolist(), c=self.c.tolist(), d=self.d.tolist(),
                    dt=self.dt, input_names=list(self.input_names), output_names=list(self.output_names),
                    input_units=list(self.input_units), output_units=list(self.output_units))


def statespace_from_dict(d: dict) -> StateSpace:
    """Inverse of :meth:`StateSpace.to_dict`.

    Examples
    --------
    >>> import numpy as np
    >>> lag = StateSpace(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.array([[0.0]]))
    >>> statespace_from_dict(lag.to_dict()).poles()
    array([-1.])
    """
    n = len(d["a"])
    m = len(d["d"][0]) if d["d"] else 0
    p = len(d["d"])
    return StateSpace(np.reshape(d["a"], (n, n)), np.reshape(d["b"], (n, m)), np.reshape(d["c"], (p, n)),
                      np.reshape(d["d"], (p, m)), float(d.get("dt", 0.0)),
                      tuple(d.get("input_names", ())), tuple(d.get("output_names", ())),
                      tuple(d.get("input_units", ())), tuple(d.get("output_units", ())))


def block_diag(*systems: StateSpace) -> StateSpace:
    """Parallel, unconnected stack of systems with one common dt.

    Examples
    --------
    >>> import numpy as np
    >>> lag = StateSpace(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.array([[0.0]]))
    >>> both = block_diag(lag, lag)
    >>> both.n_inputs, both.n_outputs, both.n_states
    (2, 2, 2)
    """
    dts = {s.dt for s in systems}
    if len(dts) != 1:
        raise ValueError(f"block_diag: systems have different sample periods {sorted(dts)}")
    return StateSpace(linalg.block_diag(*(s.a for s in systems)), linalg.block_diag(*(s.b for s in systems)),
                      linalg.block_diag(*(s.c for s in systems)), linalg.block_diag(*(s.d for s in systems)),
                      dts.pop(),
                      sum((s.input_names for s in systems), ()), sum((s.output_names for s in systems), ()),
                      sum((s.input_units for s in systems), ()), sum((s.output_units for s in systems), ()))


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """second(first(u)): output of ``first`` feeds ``second``.

    Examples
    --------
    >>> import numpy as np
    >>> lag = StateSpace(np.array([[-1.0]]), np.array([[1.0]]), np.array([[2.0]]), np.array([[0.0]]))
    >>> twice = series(lag, lag)          # 2 / (s + 1), twice: static gain 4
    >>> twice.n_states, complex(twice.freqresp(np.array([0.0]))[0, 0, 0])
    (2, (4+0j))
    """
    if first.dt != second.dt:
        raise ValueError(f"series: sample periods differ ({first.dt} vs {second.dt})")
    if first.n_outputs != second.n_inputs:
        raise ValueError(f"series: {first.n_outputs} outputs feed {second.n_inputs} inputs")
    n1 = first.n_states
    a = np.block([[first.a, np.zeros((n1, second.n_states))], [second.b @ first.c, second.a]])
    b = np.vstack([first.b, second.b @ first.d])
    c = np.hstack([second.d @ first.c, second.c])
    d = second.d @ first.d
    return StateSpace(a, b, c, d, first.dt, first.input_names, second.output_names,
                      first.input_units, second.output_units)


def delay(n_channels: int, n_samples: int, dt: float) -> StateSpace:
    """Pure delay of ``n_samples`` samples on each of ``n_channels`` channels (discrete).

    Examples
    --------
    >>> d = delay(2, 3, 1e-3)          # two channels, three samples at 1 kHz
    >>> d.n_states, d.n_inputs, d.dt
    (6, 2, 0.001)
    """
    if dt <= 0:
        raise ValueError("delay: needs a discrete sample period dt > 0")
    if n_samples == 0:
        return StateSpace(np.zeros((0, 0)), np.zeros((0, n_channels)), np.zeros((n_channels, 0)),
                          np.eye(n_channels), dt)
    n = n_channels * n_samples
    a = np.zeros((n, n))
    a[n_channels:, :-n_channels] = np.eye(n - n_channels)
    b = np.zeros((n, n_channels))
    b[:n_channels] = np.eye(n_channels)
    c = np.zeros((n_channels, n))
    c[:, -n_channels:] = np.eye(n_channels)
    return StateSpace(a, b, c, np.zeros((n_channels, n_channels)), dt)
