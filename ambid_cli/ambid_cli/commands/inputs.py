"""What the commands take from the user, checked before any work starts.

A problem with the input is a :class:`BadInput`: one line naming the
problem and the fix, which :func:`ambid_cli.cli.main` prints after the
command's name and turns into exit code 2. Option values are checked by
argparse through the ``type=`` functions here, so they fail in argparse's
own format (usage, then one line naming the option), also with exit code 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import dataclasses

from ambid.excitation.spec import KINDS, DesignSpec
from ambid.quantity import quantities

D = DesignSpec()  # the experiment identify runs: every command's defaults


class BadInput(Exception):
    """Input the command cannot use: the message is one line, the problem and the fix."""


SESSION_FIX = "give the .mcap file that 'ambid identify' or the recorder wrote"


def session_file(path: str | os.PathLike, recover: bool = False) -> str:
    """``path`` if it can be a recorded session (exists, a file, not empty, MCAP), else :class:`BadInput`.

    With ``recover`` a file whose end is missing is fine (the reader takes
    what is complete); an empty or non-MCAP file never is.
    """
    from ambid.recording import NotASessionError, check_session_file

    path = os.fspath(path)
    try:
        check_session_file(path)
    except FileNotFoundError:
        raise BadInput(f"{path}: no such file; {SESSION_FIX}") from None
    except IsADirectoryError:
        raise BadInput(f"{path} is a folder; {SESSION_FIX}") from None
    except PermissionError:
        raise BadInput(f"{path} cannot be read (permission denied); make it readable") from None
    except NotASessionError as exc:
        raise BadInput(f"{exc}; {SESSION_FIX}") from None
    return path


def ambid_topics(path: str, topic_types: dict[str, str]) -> None:
    """:class:`BadInput` unless the session's topics ({topic: type}) include one of an ambid type."""
    if not any(t.startswith("ambid_msgs/") for t in topic_types.values()):
        found = ", ".join(f"{t} ({ty})" for t, ty in sorted(topic_types.items())) or "no topics"
        raise BadInput(f"{path} holds no ambid topics (found {found}); {SESSION_FIX}")


def output_dir(path: str | os.PathLike, option: str = "--out") -> Path:
    """``path`` as a folder to write into: refused if it is an existing file (nothing is written yet)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise BadInput(f"{option} {p} is a file, not a folder; give a folder (it is created if missing)")
    return p


def output_file(path: str | os.PathLike, option: str) -> Path:
    """``path`` as a file to write: refused if it is a folder or its folder does not exist."""
    p = Path(path)
    if p.is_dir():
        raise BadInput(f"{option} {p} is a folder; give a file name")
    if not p.parent.is_dir():
        raise BadInput(f"{option} {p}: the folder {p.parent} does not exist; create it first")
    return p


def rig_file(path: str | os.PathLike | None):
    """The rig of a ``--rig`` file (None: the default rig), loaded now so a bad file stops the command
    before anything starts."""
    from ambid.plant.rig import rig_or_default

    try:
        rig = rig_or_default(path)
    except (ValueError, OSError) as exc:
        raise BadInput(str(exc)) from None
    if rig.rotor_import is not None:
        for note in rig.rotor_import.notes:  # what the import changed in the user's model, said once
            print(f"ambid: rotor file: {note}", file=sys.stderr)
    return rig


def checked_controller(spec, rig):
    """The controller ``spec`` names for ``rig`` (:func:`ambid.control.kinds.checked_design`), refused with
    :class:`BadInput` if it cannot be designed, read, or hold the rig."""
    from ambid.control.kinds import checked_design

    try:
        return checked_design(spec, rig)
    except ValueError as exc:
        raise BadInput(str(exc)) from None


def _number(kind: type, low: float, inclusive: bool, what: str):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not (value >= low if inclusive else value > low) or value != value:
            raise argparse.ArgumentTypeError(f"{text} is out of range: must be {what}")
        return value
    return parse


positive_float = _number(float, 0.0, False, "a number > 0")
positive_int = _number(int, 1, True, "a whole number >= 1")
count = _number(int, 0, True, "a whole number >= 0")


def address(text: str) -> str:
    """A ``HOST:PORT`` option value, checked (argparse type); the text is kept."""
    from ambid.hardware.rt_target import parse_address

    try:
        parse_address(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def session_id(text: str) -> int:
    """A ``--session`` value (argparse type): a session id as ambid prints it (hex)."""
    from ambid.session_id import check_session_id

    try:
        return check_session_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_run_options(p: argparse.ArgumentParser, default_namespace: str) -> None:
    """--namespace and --session of a command that starts a session (identify, graph)."""
    p.add_argument("--namespace", default=default_namespace,
                   help=f"ROS namespace of the rig (default {default_namespace}); two rigs in two namespaces run "
                        "side by side on one domain")
    p.add_argument("--session", type=session_id, default=None, metavar="ID",
                   help="the session's id, hex as printed (default: a fresh one); every node acts only on its "
                        "session's messages (docs/sessions.md)")


def controller(text: str) -> str:
    """A ``--controller`` value (argparse type): a built-in kind, or a controller file that exists."""
    from ambid.control.kinds import CONTROLLER_KINDS, FILE_SUFFIXES, is_controller_file

    if text == "" or text in CONTROLLER_KINDS:  # "": the rig file's controller, else pid
        return text
    if is_controller_file(text):
        if Path(text).is_dir():
            raise argparse.ArgumentTypeError(f"controller file {text} is a folder; give the file in it")
        if not Path(text).is_file():
            raise argparse.ArgumentTypeError(f"controller file {text} does not exist")
        return str(Path(text).resolve())
    kinds = ", ".join(CONTROLLER_KINDS)
    raise argparse.ArgumentTypeError(f"'{text}' is neither a controller kind ({kinds}) nor a controller file "
                                     f"({', '.join(FILE_SUFFIXES)})")


def add_link_options(p: argparse.ArgumentParser) -> None:
    """--key-file and --protocol-version of a command that can run against a real-time target (--hardware)."""
    p.add_argument("--key-file", default="", metavar="FILE",
                   help="with --hardware: the rig's key file, the target's own (protocol version 3; "
                        "'ambid keygen --out FILE' writes one)")
    p.add_argument("--protocol-version", type=int, choices=(2, 3), default=3,
                   help="with --hardware: 3 authenticates every datagram (default; needs --key-file), 2 is "
                        "unauthenticated and only for a target that speaks nothing else")


def hardware_link(args: argparse.Namespace) -> dict:
    """The bridge's ``protocol_version`` and ``key_file`` parameters from --protocol-version and --key-file, the
    key file read once here (a bad one stops the run before anything starts), else :class:`BadInput`."""
    from ambid.hardware.link_key import KeyFileError, read_key_file

    key_file, version = getattr(args, "key_file", ""), getattr(args, "protocol_version", 3)
    if not getattr(args, "hardware", None):
        if key_file:
            raise BadInput("--key-file without --hardware: a simulated session has no link to authenticate")
        return {}
    if version >= 3 and not key_file:
        raise BadInput("--hardware needs --key-file FILE: protocol version 3 authenticates every datagram with the "
                       "rig's key ('ambid keygen --out FILE' writes one; give the target the same file), or "
                       "--protocol-version 2 for a target that speaks only the unauthenticated version")
    if version < 3 and key_file:
        raise BadInput(f"--key-file with --protocol-version {version}: that version is unauthenticated; leave "
                       "--key-file out, or speak version 3")
    if key_file:
        try:
            read_key_file(key_file)
        except KeyFileError as exc:
            raise BadInput(str(exc)) from None
        key_file = str(Path(key_file).resolve())
    return {"protocol_version": version, "key_file": key_file}


def no_controller_on_hardware(args: argparse.Namespace) -> None:
    """:class:`BadInput` for ``--controller`` beside ``--hardware``: the target closes the loop with its own
    controller, so the option would be ignored while the summary seems to say it ran."""
    if getattr(args, "hardware", None) and getattr(args, "controller", ""):
        raise BadInput("--controller with --hardware: the real-time target runs its own controller (for the C "
                       "target, 'ambid target-model --controller ...' writes it into the model file); leave "
                       "--controller out")


def check_band(band: tuple[float, float], option: str = "--band") -> tuple[float, float]:
    """(low, high) with 0 <= low < high, else :class:`BadInput`."""
    lo, hi = band
    if not (0 <= lo < hi):
        raise BadInput(f"{option} {lo:g} {hi:g}: give LOW HIGH with 0 <= LOW < HIGH [Hz]")
    return lo, hi


def add_session_options(p: argparse.ArgumentParser) -> None:
    """--band, --resolution, --realisations and --seed of an identify session, as identify, campaign and design
    take them (the defaults: :class:`ambid.excitation.spec.DesignSpec`'s, the experiment identify runs)."""
    spec_option(p, "--band", "band_hz", nargs=2, type=float, metavar=("LO", "HI"))
    spec_option(p, "--resolution", "resolution_hz", type=positive_float)
    spec_option(p, "--realisations", "n_realisations", type=positive_int)
    spec_option(p, "--seed", "seed", type=int, help="seed of the random phases and of the simulated noise")


def add_experiment_options(p: argparse.ArgumentParser) -> None:
    """The rest of the experiment's terms, as identify and design take them, with DesignSpec's defaults."""
    spec_option(p, "--kind", "kind", choices=KINDS, help="excitation kind")
    spec_option(p, "--peak-current", "peak_current_a", type=positive_float)
    spec_option(p, "--periods", "n_periods", type=positive_int)
    spec_option(p, "--transient-periods", "n_transient_periods", type=count)
    spec_option(p, "--grid", "grid")
    spec_option(p, "--spacing", "spacing")
    spec_option(p, "--phases", "phases")
    spec_option(p, "--mimo", "mimo")


def spec_option(p: argparse.ArgumentParser, flag: str, field: str, **kw) -> None:
    """The option ``flag`` for :class:`DesignSpec`'s ``field``: its dest is the field's name, its default the
    field's, its help the field's description (``ambid.quantity``) unless ``help`` is given, so the option
    repeats none of them and :func:`experiment_spec` reads it by the field's name."""
    described = {name: q.description() for name, _, q in quantities(DesignSpec)}
    default = getattr(D, field)
    if isinstance(default, tuple):
        shown = " ".join(f"{v:g}" for v in default)
    else:
        shown = f"{default:g}" if isinstance(default, (int, float)) else default
    text = kw.pop("help", None) or described[field]
    if "choices" not in kw:   # the usage line as before: --peak-current PEAK_CURRENT
        kw.setdefault("metavar", flag.lstrip("-").replace("-", "_").upper())
    p.add_argument(flag, dest=field, default=default, help=text + (f" (default {shown})" if shown else ""), **kw)


def check_amplifier(design, current_limit_a: float, working_current_a: float, rig=None) -> None:
    """BadInput when ``design``'s peak plus the controller's working current exceeds the amplifier's limit
    (:func:`ambid.excitation.check_headroom`): the refusal the excitation generator would give once the
    nodes run, given before anything starts, in the command's terms. With ``rig``, also when following the
    excitation would ask the amplifier for more voltage than its dc link has (:func:`voltage_needs`); the
    peak current suggested fits both."""
    import numpy as np
    from ambid.excitation import check_headroom

    volts = voltage_needs(design, rig, working_current_a) if rig is not None else []
    over_v = [v for v in volts if v[1] > v[2]]
    fits_v = min((v[3] for v in volts), default=np.inf)
    try:
        check_headroom(design, current_limit_a, working_current_a)
    except ValueError:
        over = [n for n, pk in zip(design.input_names, design.peak_a) if pk + working_current_a > current_limit_a]
        left = min(max(current_limit_a - working_current_a, 0.0), fits_v)
        raise BadInput(f"the excitation peak {float(np.max(design.peak_a)):.3g} A plus the controller's working "
                       f"current {working_current_a:g} A exceeds the amplifier's {current_limit_a:g} A limit on "
                       f"{', '.join(over)}; give --peak-current {left:.3g} or less") from None
    if over_v:
        name, need, udc, _ = max(over_v, key=lambda v: v[1] / v[2])
        raise BadInput(f"the excitation's steps on {name} need {need:.4g} V of the amplifier's {udc:g} V dc link to "
                       f"be followed within a sample (L di/dt + R i); give --peak-current {fits_v:.3g} or less, or "
                       "a lower band")


def voltage_needs(design, rig, working_current_a: float) -> list[tuple[str, float, float, float]]:
    """Per input of ``design``: (name, the voltage its steps need to be followed within a sample, the dc link's
    voltage, the peak current whose steps it can follow) (:func:`ambid.plant.amplifier.slew_voltage_v`).

    Beyond the dc link the amplifier would saturate, the coil current slew behind the excitation designed and
    the FRF measure that distortion. The controller's own share (its noise, its response) is not counted:
    what is refused is what cannot be followed at all."""
    from ambid.plant.amplifier import slew_voltage_v

    import numpy as np

    names = list(rig.layout.inputs)
    if design.is_periodic:
        # the steady state the FRF is measured in: each segment's period, closed on itself (the jump from one
        # segment to the next falls in the settling periods, which are not measured)
        x = np.concatenate([np.concatenate([p, p[:1], np.full((1, design.n_inputs), np.nan)])
                            for m in range(design.n_realisations) for e in range(design.n_experiments)
                            for p in [design.period(m, e)]])
    else:
        x = design.samples(0, design.total_samples)
    out = []
    for i, name in enumerate(design.input_names):
        axial = name in names and names.index(name) in rig.layout.axial
        amp = rig.axial_amplifier if axial else rig.amplifier
        offset = rig.values["axial_bias_current_a" if axial else "bias_current_a"] + working_current_a
        need = float(slew_voltage_v(amp, x[:, i], design.dt_s, offset))
        static = amp.resistance_ohm * offset   # the share that does not grow with the peak
        udc = amp.dc_link_voltage_v
        out.append((name, need, udc, float(design.peak_a[i]) * max(udc - static, 0.0) / max(need - static, 1e-300)))
    return out


def experiment_spec(args: argparse.Namespace, **terms) -> DesignSpec:
    """The DesignSpec of the options ``args`` holds (DesignSpec's defaults for those it does not) and
    ``terms``; the band is checked (:func:`check_band`)."""
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(DesignSpec) if hasattr(args, f.name)}
    if "band_hz" in given:
        given["band_hz"] = check_band(tuple(given["band_hz"]))
    return DesignSpec(**{**given, **terms})



def port_number(text: str) -> int:
    """A TCP port (argparse type): 0..65535, 0 for any free one."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number (0..65535)") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text} is out of range: a port is 0..65535")
    return value


def add_live_options(p: argparse.ArgumentParser) -> None:
    """--live PORT and --live-host HOST: the Foxglove live view of a running session (docs/live.md)."""
    p.add_argument("--live", type=port_number, metavar="PORT",
                   help="show the session live in Foxglove: a WebSocket server on PORT (0: any free one); "
                        "see docs/live.md")
    p.add_argument("--live-host", default="127.0.0.1", metavar="HOST",
                   help="address the live view binds (default 127.0.0.1: this machine only; 0.0.0.0: every "
                        "interface)")


def free_port(host: str, port: int, option: str = "--live") -> None:
    """:class:`BadInput` unless ``host:port`` can be listened on now (checked before anything starts)."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
    except OSError as exc:
        raise BadInput(f"{option} {port}: cannot listen on {host}:{port} ({exc.strerror or exc}); choose another "
                       "port, or free this one") from None
