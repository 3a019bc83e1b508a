"""ambid keygen: write a rig's link key file (protocol version 3, docs/bridge_protocol.md)."""

from __future__ import annotations

import argparse

from ambid_cli.commands.inputs import BadInput

HELP = "write a new link key file for a rig's bridge and real-time target (mode 0600; protocol version 3)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="key file to create (never over an existing file)")


def run(args: argparse.Namespace) -> int:
    from ambid.hardware.link_key import KeyFileError, write_key_file

    try:
        key = write_key_file(args.out)
    except KeyFileError as exc:
        raise BadInput(str(exc)) from None
    print(f"ambid keygen: {args.out}: a new link key, fingerprint {key.fingerprint} (mode 0600); give the same file "
          "to the bridge (--key-file, parameter key_file) and the target (--key-file)")
    return 0
