"""A Foxglove WebSocket client, as the Foxglove app is one: for the live view's benchmark and tests.

It speaks the protocol (``foxglove.sdk.v1``, the subprotocol foxglove-sdk's
server answers; ``foxglove.websocket.v1`` offered too, as the app does) over
the ``websockets`` package: it subscribes to every channel the server
advertises and decodes each message (opcode 1: subscription id, log time,
payload; JSON here). As a process (``python -m ambid_cli.bench.foxglove_client
URL``) it reads until the server closes and prints one JSON line of what it
got, per topic, and the CPU seconds it took from connecting to the end
(``cpu_s``).
"""

from __future__ import annotations

import asyncio
import json
import struct
import sys
import time
from collections.abc import Callable

PROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
CONNECTED = "connected"   # the process's first line, once its connection is open
UNKNOWN = "Unknown channel ID: "   # the status foxglove-sdk sends for a subscription it dropped


async def follow(url: str, on_message: Callable[[str, int, dict], None], connect_timeout_s: float = 60.0,
                 on_channels: Callable[[list[dict]], None] | None = None,
                 on_connected: Callable[[], None] | None = None) -> None:
    """Connect to ``url`` (retrying until it listens), subscribe to every advertised channel, and call
    ``on_message(topic, log_time_ns, message)`` for each message, until the server closes the connection
    (``on_connected()`` once the connection is open)."""
    import websockets

    end = time.monotonic() + connect_timeout_s
    while True:
        try:
            ws = await websockets.connect(url, subprotocols=PROTOCOLS, max_size=None, open_timeout=10)
            break
        except (OSError, websockets.exceptions.InvalidHandshake, asyncio.TimeoutError):
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.2)
    if on_connected is not None:
        on_connected()
    subs: dict[int, dict] = {}
    try:
        async for raw in ws:
            if isinstance(raw, str):
                m = json.loads(raw)
                if m.get("op") == "advertise":
                    new = []
                    for c in m["channels"]:
                        subs[len(subs) + 1] = c
                        new.append({"id": len(subs), "channelId": c["id"]})
                    if on_channels is not None:
                        on_channels(m["channels"])
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                elif m.get("op") == "status" and str(m.get("message", "")).startswith(UNKNOWN):
                    # foxglove-sdk 0.30 can answer a subscription to a channel it has just advertised with
                    # "Unknown channel ID" (it sends the advertisement before it knows the channel for that
                    # client): the subscription was dropped, so it is asked for again, once the server caught up
                    cid = int(str(m["message"])[len(UNKNOWN):])
                    again = [{"id": sid, "channelId": cid} for sid, c in subs.items() if c["id"] == cid]
                    await asyncio.sleep(0.05)
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": again}))
            elif raw and raw[0] == 1:   # MessageData: opcode, subscription id (u32), log time (u64), payload
                sub_id, t_ns = struct.unpack_from("<IQ", raw, 1)
                c = subs.get(sub_id)
                if c is not None and c.get("encoding") == "json":
                    on_message(c["topic"], t_ns, json.loads(raw[13:]))
    except websockets.exceptions.ConnectionClosed:
        pass
    finally:
        await ws.close()


def main(argv: list[str] | None = None) -> int:
    import websockets  # noqa: F401 - imported before the clock starts: the app is running already

    argv = sys.argv[1:] if argv is None else argv
    url = argv[0]
    cpu0 = time.process_time()
    counts: dict[str, int] = {}
    channels: list[dict] = []

    def on_message(topic: str, t_ns: int, msg: dict) -> None:
        counts[topic] = counts.get(topic, 0) + 1

    # "connected" first: the bench starts its session once the viewer is there, as a user opens Foxglove first
    asyncio.run(follow(url, on_message, on_channels=channels.extend,
                       on_connected=lambda: print(CONNECTED, flush=True)))
    print(json.dumps({"channels": sorted(c["topic"] for c in channels), "messages": counts,
                      "total": sum(counts.values()), "cpu_s": time.process_time() - cpu0}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
