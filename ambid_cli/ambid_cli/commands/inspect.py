"""ambid inspect: what a recorded MCAP session holds (never imports rclpy).

Topics, types, message counts, duration and rates; sample-index gaps of the
SampleBlock topics (measurement, excitation) from the block headers; the rig,
controller and excitation designs in short, from the session facts the
recorder stored as metadata or, for files without them (``ros2 bag record``),
from the recorded latched description messages. ``--recover`` reads a file a
killed recorder left (no summary, truncated last chunk) and reports how many
messages it recovered.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from ambid.recording import IncompleteSessionError, format_inspection, inspect_session, iter_decoded
from ambid.recording.blocks import SAMPLE_BLOCK_TYPE, sample_index_report
from ambid.recording.facts import FACT_TYPES, controller_facts, design_facts, design_summary, plant_facts, rig_summary

HELP = "inspect a recorded MCAP session: topics, rates, sample gaps, design and rig"
SESSION_RECORD = "ambid.session"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="session .mcap file")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.add_argument("--recover", action="store_true",
                   help="read a file a killed recorder left (no summary/footer) as far as it is complete")


def _parsed(value: str) -> Any:
    try:
        return json.loads(value)
    except (json.JSONDecodeError, TypeError):
        return value


def _facts_from_messages(path: str, topics: dict[str, dict]) -> dict[str, Any]:
    """Facts from the recorded latched messages, for files without ``ambid.session`` metadata."""
    wanted = {t: FACT_TYPES[info["type"]] for t, info in topics.items()
              if info["type"] in FACT_TYPES and info["message_count"]}
    facts: dict[str, Any] = {}
    if not wanted:
        return facts
    for msg, decoded in iter_decoded(path, list(wanted), recover=True):
        key = wanted[msg.topic]
        if key == "plant":
            facts["plant"] = plant_facts(decoded)
            facts["rig"] = facts["plant"]["rig"]
        elif key == "controller":
            facts["controller"] = controller_facts(decoded)
        else:
            facts.setdefault("excitation", {})[str(decoded.experiment_id)] = design_facts(decoded)
    return facts


def session_facts(path: str, report: dict) -> dict[str, Any]:
    """Rig, plant, controller and excitation facts in short; ``source`` says where they came from."""
    stored = {k: _parsed(v) for k, v in report["metadata"].get(SESSION_RECORD, {}).items()}
    decoded = {}
    if not all(k in stored for k in ("plant", "controller")):
        decoded = _facts_from_messages(path, report["topics"])
    facts = {**decoded, **stored}
    plant = facts.get("plant") if isinstance(facts.get("plant"), dict) else {}
    controller = facts.get("controller") if isinstance(facts.get("controller"), dict) else {}
    designs = facts.get("excitation") if isinstance(facts.get("excitation"), dict) else {}
    return {
        "source": "+".join(name for name, found in (("metadata", stored), ("messages", decoded)) if found)
                  or "none",
        "ambid_version": facts.get("ambid_version"),
        "log_time": facts.get("log_time"),
        "rig": rig_summary(facts.get("rig", plant.get("rig", {}))),
        "plant": {k: v for k, v in plant.items() if k != "rig"},
        "controller": controller,
        # the full designs (amplitudes, phases) stay in report["metadata"]
        "excitation": {eid: dict({k: v for k, v in d.items() if k != "design"},
                                 excitation_units=_excitation_units(d, facts.get("import")))
                       for eid, d in designs.items() if isinstance(d, dict)},
    }


def _excitation_units(design: dict, imported: Any) -> list[str]:
    """The unit of each excitation channel of ``design``: an imported record's MAP.yaml units (an excitation
    injected at the reference is in V or m), else A (ambid's own sessions add it to the current)."""
    units = imported.get("units", {}) if isinstance(imported, dict) else {}
    names = design.get("input_names") or []
    return [str(units.get("r_" + str(n).split("_", 1)[-1], "A")) for n in names]


def describe(path: str, recover: bool = False) -> dict[str, Any]:
    """The inspection report of one session (JSON-able dict).

    Keys of :func:`ambid.recording.inspect_session` (with ``sample_index``
    computed from the block headers), plus ``facts`` (:func:`session_facts`)
    and ``recovery`` ({complete, recovered_messages, valid_bytes, file_bytes,
    problem}).

    Raises:
        IncompleteSessionError: if the file has no footer and ``recover`` is False.
        ValueError: if the file is not MCAP.
    """
    report = inspect_session(path, recover=recover)
    blocks = [t for t, info in report["topics"].items() if info["type"] == SAMPLE_BLOCK_TYPE]
    # header-only parse: a generic CDR decode of a 1000 x 16 block costs ~36 ms, this a few us
    report["sample_index"] = sample_index_report(path, blocks, recover=True)
    report["facts"] = session_facts(path, report)
    valid = report["file_bytes"] if report["complete"] else _valid_bytes(path)
    report["recovery"] = {"complete": report["complete"], "recovered_messages": report["message_count"],
                          "valid_bytes": valid, "file_bytes": report["file_bytes"], "problem": report["problem"]}
    return report


def _valid_bytes(path: str) -> int:
    from ambid.recording import scan_session

    return scan_session(path).valid_bytes


def format_report(report: dict) -> str:
    lines = [format_inspection(report)]
    facts = report["facts"]
    lines.append("")
    lines.append(f"session facts (from {facts['source']}), ambid {facts.get('ambid_version') or '?'}")
    rig = facts["rig"]
    if rig:
        lines.append("  rig         " + ", ".join(f"{k}={v}" for k, v in rig.items()))
    plant = facts["plant"]
    if plant:
        lines.append(f"  plant       {plant.get('name')} ({plant.get('source')}), "
                     f"T={plant.get('sample_period_s')} s, seed {plant.get('seed')}")
    ctrl = facts["controller"]
    if ctrl:
        lines.append(f"  controller  {ctrl.get('kind')}, delay {ctrl.get('delay_samples')} samples, "
                     f"{ctrl.get('n_states')} states, parameters {json.dumps(ctrl.get('parameters'))}")
    for design in facts["excitation"].values():
        lines.append("  excitation  " + design_summary(design))
    if not (rig or plant or ctrl or facts["excitation"]):
        lines.append("  none recorded")
    rec = report["recovery"]
    if not rec["complete"]:
        lines.append("")
        lines.append(f"RECOVERED {rec['recovered_messages']} messages from an incomplete file "
                     f"({rec['valid_bytes']} of {rec['file_bytes']} bytes readable): {rec['problem']}. "
                     "The recorder did not close it (killed, crashed or disk full); what it had not "
                     "flushed is lost.")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ambid_cli.commands.inputs import BadInput, ambid_topics, session_file

    path = session_file(args.file, args.recover)
    try:
        report = describe(path, recover=args.recover)
    except IncompleteSessionError as exc:
        raise BadInput(f"{exc}; the recorder was killed or the disk filled up: run 'ambid inspect --recover "
                       f"{path}' to read what it wrote") from None
    except ValueError as exc:
        raise BadInput(f"{exc}; {path} cannot be read as a session") from None
    ambid_topics(path, {t: info["type"] for t, info in report["topics"].items()})
    if args.json:
        print(json.dumps(report, indent=1, default=str))
    else:
        print(format_report(report))
    return 0
