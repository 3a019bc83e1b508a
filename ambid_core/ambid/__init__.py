"""ambid: system identification of active-magnetic-bearing rotor systems.

The numerical core: AMB models, controllers, excitation design, FRF
estimation, fitting, model updating and session I/O, in plain numpy/scipy;
nothing in this package imports ROS. The public API (:mod:`ambid.api`):

>>> import ambid
>>> s = ambid.read_session(session_path)          # e.g. "identify/session.mcap"
>>> frf = ambid.estimate_frf(s)
>>> m = ambid.fit_model(frf)
>>> [round(mode.freq_hz) for mode in m.modes if mode.stable]
[177, 310, 927]

``read_session``, ``estimate_frf``, ``fit_model``, ``update_model``,
``design_excitation``, ``import_record``, ``load_rig``; the rooms below
(``ambid.frf``, ``ambid.fit``, ...) hold everything else.
"""

from ambid.version import __version__

API = ("read_session", "estimate_frf", "fit_model", "update_model", "design_excitation", "import_record",
       "load_rig")
__all__ = ["__version__", *API]


def __getattr__(name: str):
    # the API is loaded on first use: every 'import ambid.<room>' runs this file first, and a node
    # importing ambid.channels must not pay for scipy's fitting and the whole identification
    if name in API:
        from ambid import api

        return getattr(api, name)
    raise AttributeError(f"module 'ambid' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *API])
