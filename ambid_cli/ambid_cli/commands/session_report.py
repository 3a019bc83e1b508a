"""The lines identify and graph print about their session: its id, foreign publishers found before it
started, and a node's death that ended it (docs/sessions.md)."""

from __future__ import annotations

import sys

from ambid.session_id import format_session, new_session_id


def session_of(args) -> int:
    """The session a command starts: ``--session`` or a fresh id."""
    return args.session if args.session is not None else new_session_id()


def _by_publisher(pairs) -> str:
    """``who on a, b; other on c`` from (publisher, what) pairs, publishers sorted, each one's in the given order."""
    by_who: dict[str, list[str]] = {}
    for who, what in pairs:
        by_who.setdefault(who, []).append(what)
    return "; ".join(f"{who} on {', '.join(items)}" for who, items in sorted(by_who.items()))


def foreign_line(command: str, foreign: dict[str, list[str]]) -> str | None:
    """One line naming the publishers found on the rig's topics before the session started, grouped by publisher;
    None if there were none."""
    if not foreign:
        return None
    found = _by_publisher((who, topic) for topic, names in foreign.items() for who in names)
    return (f"ambid {command}: foreign publishers on this rig's topics, ignored (their messages are counted, "
            f"never acted on nor recorded): {found}")


def kept_out_line(command: str, kept_out: dict[str, dict]) -> str | None:
    """One line of the foreign messages the session heard and kept out ({topic: {"messages": n, "from":
    [publishers]}}, the recorder's count), grouped by publisher; None if there were none. Said after the session
    whether or not they were found before it (a source that appears later, or is discovered late, is named here)."""
    if not kept_out:
        return None
    found = _by_publisher((who, f"{topic} ({f['messages']})") for topic, f in sorted(kept_out.items())
                          for who in f.get("from") or ["an unnamed publisher"])
    return (f"ambid {command}: foreign messages heard during the session and kept out of it (messages per topic): "
            f"{found}")


def live_line(live: dict) -> str:
    """The live view's figures at the end: frames sent, clients, frames dropped, blocks lost and the foreign
    messages it did not show."""
    n = sum((live.get("foreign_messages") or {}).values())
    return (f"live view: {live.get('frames_sent', 0)} frames sent to {live.get('clients', 0)} client(s), "
            f"{live.get('dropped_frames', 0)} dropped, {live.get('lost_blocks', 0)} blocks lost"
            + (f", {n} foreign messages not shown" if n else ""))


def print_foreign(command: str, foreign: dict[str, list[str]]) -> None:
    line = foreign_line(command, foreign)
    if line:
        print(line, file=sys.stderr, flush=True)


def death_line(command: str, death: dict) -> str:
    """``ambid graph: position_controller was killed (SIGKILL); the session ended at sample 80123 (8.012 s
    simulated): the plant went to its safe state there, the rotor landed``."""
    return (f"ambid {command}: {death['node']} {death['how']}; the session ended at sample {death['sample_index']} "
            f"({death['simulated_s']:.3f} s simulated): {death['consequence']}")


def session_words(session: int) -> str:
    return f"session {format_session(session)}"


def levitation_lines(f: dict) -> str:
    """The displacement figures and the samples they were judged over."""
    if not f.get("samples_evaluated"):
        return (f"displacement RMS: no samples to judge (the run ended at sample {f.get('samples')}, before its "
                f"judged window; lift-off at sample {f.get('lift_off_index')})")
    axes = f" over {len(f['displacement_mean_m'])} axes," if f.get("displacement_mean_m") is not None else ""
    return (f"displacement RMS: {f['displacement_rms_m'] * 1e6:.3f} um{axes} over samples [{f['evaluated_from_index']}, "
            f"{f['evaluated_to_index']}) (max {f['max_abs_displacement_m'] * 1e6:.2f} um, lift-off at sample "
            f"{f['lift_off_index']})")
