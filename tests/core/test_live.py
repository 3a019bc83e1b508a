"""The live view's core (ambid.live): frames from a session as it streams, and the Foxglove server.

The session is the simulated 2x2 closed loop of frf_testbench, its channels named as a rig with one radial
bearing (y_a_x, y_a_y: one orbit, never four axes assumed), excited by an orthogonal multisine and fed in
blocks. The server is foxglove-sdk's, read by a client that speaks the Foxglove WebSocket protocol over the
``websockets`` package, as the Foxglove app does.
"""

import asyncio
import json
import socket
import struct
import threading
import time
import types

import numpy as np
import pytest
from ambid.excitation import design_multisine
from ambid.frf.streaming import FrfStream
from ambid.live.follower import SessionFollower
from ambid.live.frames import SCHEMAS
from ambid.live.layout import foxglove_layout
from ambid.live.server import LiveServer
from frf_testbench import FS, loop_model, simulate

NAMES = ("y_a_x", "y_a_y", "u_a_x", "u_a_y", "r_a_x", "r_a_y")
PRE, POST = 300, 500


@pytest.fixture(scope="module")
def session():
    d = design_multisine((20.0, 600.0), 20.0, FS, ("u_a_x", "u_a_y"), 0.3, n_periods=3, n_realisations=2,
                         n_transient_periods=1, grid="random_odd", seed=3)
    r = np.zeros((PRE + d.total_samples + POST, 2))
    r[PRE:PRE + d.total_samples] = d.samples(0, d.total_samples)
    y, u = simulate(loop_model(), r[None], 1e-7, 1)
    return d, np.hstack([y[0], u[0], r])


def _follow(design, x, block=700, skip=()):
    """Every block through a follower, shown after each (as a server with display_hz 0 does)."""
    f = SessionFollower(signal_rate_hz=500.0, orbit_points=50)
    frames = f.design_message("exp1", design, PRE, design.total_samples)
    for k in range(0, len(x), block):
        if k in skip:
            continue
        frames += f.block(k, 1 / FS, NAMES, x[k:k + block]) + f.display_frames()
    return f, frames + f.display_frames(final=True)


def test_the_last_frf_frames_are_the_whole_records_estimate(session):
    d, x = session
    f, frames = _follow(d, x, block=250)   # blocks shorter than a period: each period ends in its own block
    ref = FrfStream(d, NAMES[:2], NAMES[2:4], NAMES[4:], start_index=PRE)
    ref.add(0, x)
    final = ref.estimate("indirect")
    frf = [fr for fr in frames if fr.schema_name == "ambid.live.FrfEntry"]
    # the entries' channels advertised as the experiment starts (no message yet), then one estimate after every
    # period that completed a record (in all Ne = 2 experiments): P = 3, M = 2
    assert [fr.message for fr in frf[:4]] == [None] * 4
    frf = frf[4:]
    assert f.counts["estimates"] == d.n_realisations * d.n_periods
    assert len(frf) == 4 * f.counts["estimates"]
    last = {(m.message["output"], m.message["input"]): m.message for m in frf[-4:]}
    for i, out in enumerate(NAMES[:2]):
        for j, inp in enumerate(NAMES[2:4]):
            m = json.loads(json.dumps(last[out, inp]))          # what a client decodes
            assert m["complete"] and m["records"] == 6 and m["realisations"] == 2 and m["band"] == "total"
            g = np.array(m["real"]) + 1j * np.array(m["imag"])
            np.testing.assert_array_equal(g, final.frf[:, i, j])   # JSON floats round-trip exactly
            np.testing.assert_array_equal(m["freq_hz"], final.freq_hz)
            db = dict(rtol=0, atol=0.5e-4)   # the dB and degree arrays are rounded to 1e-4
            np.testing.assert_allclose(m["magnitude_db"], 20 * np.log10(np.abs(final.frf[:, i, j])), **db)
            np.testing.assert_allclose(m["phase_deg"], np.angle(final.frf[:, i, j], deg=True), **db)
            s2 = 2 * np.sqrt(final.var_total[:, i, j])
            np.testing.assert_allclose(m["magnitude_db_upper"], 20 * np.log10(np.abs(final.frf[:, i, j]) + s2), **db)
            assert np.all(np.array(m["phase_deg_lower"]) <= np.array(m["phase_deg"]))
            np.testing.assert_allclose(m["noise_db"], 10 * np.log10(final.var_noise[:, i, j]), **db)
    # the first estimate came from the first realisation's records before it ended (a live preview)
    first = frf[0].message
    assert first["records"] == 1 and first["realisations"] == 1 and not first["complete"]
    levels = [fr.message for fr in frames if fr.schema_name == "ambid.live.Levels"]
    assert {m["output"] for m in levels[-2:]} == set(NAMES[:2])
    assert len(levels[-1]["freq_hz"]) == d.detection_lines_odd.size + d.detection_lines_even.size
    assert levels[-1]["odd_db"] == pytest.approx(final.distortion.odd_db[1])


def test_signals_orbit_and_progress_follow_the_layout(session):
    d, x = session
    f, frames = _follow(d, x)
    sig = [fr for fr in frames if fr.topic == "signals" and fr.message is not None]
    shown = ["y_a_x", "y_a_y", "u_a_x", "u_a_y"]
    assert set(sig[0].message) == {"t_s", *shown}
    # the envelope: a pair per block (each spans 700 samples, more than 1 / signal_rate_hz), each channel's minimum
    # stamped at the block's first sample, then its maximum at its last: no peak lost, whatever came between
    starts = range(0, len(x), 700)
    assert len(sig) == 2 * len(starts)
    for k, lo, hi in zip(starts, sig[::2], sig[1::2]):
        rows = x[k:k + 700, :4]
        assert [lo.message[n] for n in shown] == rows.min(axis=0).tolist()
        assert [hi.message[n] for n in shown] == rows.max(axis=0).tolist()
        assert (lo.t_ns, hi.t_ns) == (round(k / FS * 1e9), round((k + len(rows) - 1) / FS * 1e9))
    orbits = [fr for fr in frames if fr.schema_name == "ambid.live.Orbit" and fr.message is not None]
    assert {o.topic for o in orbits} == {"orbit/a"}           # one radial pair: one bearing, one orbit
    o = orbits[0].message
    assert (o["x_channel"], o["y_channel"]) == ("y_a_x", "y_a_y") and len(o["x_m"]) == 50
    # every 14th sample of the block (50 points of 700), to 5 significant digits of the largest
    peak = np.abs(x[:700, 0]).max()
    np.testing.assert_allclose(o["x_m"], x[:700:14, 0], rtol=0, atol=0.5e-4 * peak)
    assert len(json.dumps(o["x_m"])) < 0.7 * len(json.dumps(x[:700:14, 0].tolist()))
    prog = [fr.message for fr in frames if fr.topic == "progress"]
    assert prog[-1]["finished"] and prog[-1]["fraction"] == 1.0 and prog[-1]["lost_blocks"] == 0
    assert prog[-1]["periods_done"] == prog[-1]["periods"] == d.n_realisations * d.n_experiments * d.n_periods
    for fr in (fr for fr in frames if fr.message is not None):   # every message fits its schema's fields
        props = SCHEMAS[fr.schema_name]["properties"]
        extra = SCHEMAS[fr.schema_name].get("additionalProperties")
        assert extra or set(fr.message) <= set(props), (fr.schema_name, set(fr.message) - set(props))


def test_lost_blocks_are_counted_and_their_periods_left_out(session):
    d, x = session
    f, _ = _follow(d, x, skip=(1400,))   # samples 1400..2099: the first experiment's steady state
    assert f.counts["lost_blocks"] == 1 and f.counts["lost_samples"] == 700
    assert f.result.gaps and f.result.n_periods < d.n_realisations * d.n_periods
    assert f.figures()["frf_gaps"] == 1 and f.figures()["frf_gap_samples"] == 700


def test_a_live_view_that_joins_late_says_what_its_frf_misses(session):
    d, x = session
    f = SessionFollower()
    f.design_message("exp1", d, PRE, d.total_samples)
    for k in range(2000, len(x), 500):   # the first 2000 samples never came: 1700 of the experiment's
        f.block(k, 1 / FS, NAMES, x[k:k + 500])
    fig = f.figures()
    assert fig["lost_blocks"] == 0 and fig["frf_gaps"] == 1 and fig["frf_gap_samples"] == 2000 - PRE
    assert fig["finished"] and fig["periods_done"] < fig["periods"]


def test_server_streams_to_a_foxglove_client_and_a_late_one_gets_the_latest(session):
    d, x = session
    server = LiveServer(0, prefix="/amb/live", follower=SessionFollower(signal_rate_hz=100.0)).start()
    try:
        got = asyncio.run(_client(server, d, x))
    finally:
        figures = server.close()
    topics = {c["topic"] for c in got["channels"]}
    assert {"/amb/live/frf/y_a_x/u_a_y", "/amb/live/orbit/a", "/amb/live/signals", "/amb/live/progress",
            "/amb/live/levels/y_a_y"} <= topics
    assert all(c["encoding"] == "json" and c["schemaEncoding"] == "jsonschema" for c in got["channels"])
    final = [m for m in got["messages"]["/amb/live/frf/y_a_y/u_a_x"] if m["complete"]]
    assert final, "the final estimate reached the client"
    ref = FrfStream(d, NAMES[:2], NAMES[2:4], NAMES[4:], start_index=PRE)
    ref.add(0, x)
    np.testing.assert_array_equal(np.array(final[-1]["real"]) + 1j * np.array(final[-1]["imag"]),
                                  ref.estimate().frf[:, 1, 0])
    assert got["late"]["complete"], "a client subscribing after the end got the latest FRF at once"
    assert figures["frames_sent"] > 0 and figures["dropped_frames"] == 0 and figures["clients"] == 2


async def _client(server, design, x):
    import websockets
    from ambid_cli.bench.foxglove_client import UNKNOWN

    url = f"ws://127.0.0.1:{server.port}"
    protocols = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
    channels, subs, messages = [], {}, {}
    async with websockets.connect(url, subprotocols=protocols, max_size=None) as ws:
        info = json.loads(await ws.recv())
        assert info["op"] == "serverInfo"

        def feed():   # as a session does: the design, then a block every 50 ms
            server.submit("design_message", "exp1", design, PRE, design.total_samples)
            for k in range(0, len(x), 1000):
                time.sleep(0.05)
                server.submit("block", k, 1 / FS, NAMES, x[k:k + 1000])

        async def subscribe_new(adv):
            new = []
            for c in adv["channels"]:
                channels.append(c)
                subs[len(subs) + 1] = c
                new.append({"id": len(subs), "channelId": c["id"]})
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))

        feeder = threading.Thread(target=feed)
        feeder.start()
        finished = False

        def complete() -> bool:   # the checked entry's final estimate is in
            return any(m.get("complete") for m in messages.get("/amb/live/frf/y_a_y/u_a_x", []))

        while True:   # until the session finished, its final estimate came and nothing more for a second
            try:
                raw = await asyncio.wait_for(ws.recv(), 1.0 if finished and complete() else 60.0)
            except asyncio.TimeoutError:
                break
            if isinstance(raw, str):
                m = json.loads(raw)
                if m["op"] == "advertise":
                    await subscribe_new(m)
                elif m["op"] == "status" and str(m.get("message", "")).startswith(UNKNOWN):
                    # foxglove-sdk 0.30 drops, now and then, a subscription to a channel it advertised as the
                    # client connected: asked for again, as the bench's client and the app's user do
                    cid = int(m["message"][len(UNKNOWN):])
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": sid, "channelId": cid} for sid, c in subs.items() if c["id"] == cid]}))
            else:
                assert raw[0] == 1          # MessageData: opcode, subscription id, log time, payload
                sub_id, _t = struct.unpack_from("<IQ", raw, 1)
                c = subs[sub_id]
                msg = json.loads(raw[13:])
                messages.setdefault(c["topic"], []).append(msg)
                finished = finished or (c["topic"].endswith("progress") and msg.get("finished"))
        feeder.join()
        server.drain()
    # a second client, after the session: it gets each channel's latest message on subscribing
    async with websockets.connect(url, subprotocols=protocols, max_size=None) as ws:
        await ws.recv()
        adv = json.loads(await ws.recv())
        c = next(c for c in adv["channels"] if c["topic"] == "/amb/live/frf/y_a_y/u_a_x")
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": c["id"]}]}))
        raw = await asyncio.wait_for(ws.recv(), 10.0)
        late = json.loads(raw[13:])
    return {"channels": channels, "messages": messages, "late": late}


def test_a_client_that_never_reads_costs_bounded_memory():
    """A client subscribes to everything and never reads: the server keeps at most `backlog` messages for it,
    so 60+ MB of frames pass through while the process grows by a fraction of that (64 x 80 kB queued)."""
    import resource

    # big orbit frames (2 x 5000 floats, ~80 kB each), hardly any others
    server = LiveServer(0, backlog=64, follower=SessionFollower(signal_rate_hz=0.1, orbit_points=5000)).start()
    payload = np.random.default_rng(0).standard_normal((1000, 6))
    sock = socket.create_connection(("127.0.0.1", server.port))
    reader = sock.makefile("rb")
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        key = "dGhlIHNhbXBsZSBub25jZQ=="
        sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                      f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                      "Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode())
        # the first block's frames advertise the channels; subscribe to every one, then read nothing more
        server.submit("block", 0, 1 / FS, NAMES, payload)
        assert server.drain()
        while reader.readline() not in (b"\r\n", b""):   # the HTTP 101 answer
            pass
        ids = []
        while len(ids) < server.figures()["channels"]:
            op, body = _frame(reader)
            m = json.loads(body) if op == 1 else {}
            ids += [c["id"] for c in m.get("channels", [])] if m.get("op") == "advertise" else []
        body = json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": c}
                                                                for i, c in enumerate(ids)]}).encode()
        sock.sendall(bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(body)) + b"\0\0\0\0" + body)
        time.sleep(0.5)
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        big = np.tile(payload, (10, 1))      # 10,000 samples a block
        sent0 = server.figures()["bytes_sent"]
        for k in range(1, 1200):
            server.submit("block", 10_000 * k, 1 / FS, NAMES, big)
            if k % 20 == 0:
                server.drain(30.0)
        assert server.drain(30.0)
        sent = server.figures()["bytes_sent"] - sent0
        grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
        figures = server.close()   # with the stalled client still connected: closing must not wait for it
    finally:
        reader.close()
        sock.close()
        server.close()
    assert sent > 60e6, f"the frames were encoded and handed to the server (the client subscribed) {figures}"
    assert grown_mb < 60, f"{grown_mb:.0f} MB more for {sent / 1e6:.0f} MB a stalled client never read"


def _frame(reader) -> tuple[int, bytes]:
    """One WebSocket frame a server sent (unmasked): (opcode, payload)."""
    b0, b1 = reader.read(2)
    n = b1 & 0x7F
    if n == 126:
        n = struct.unpack(">H", reader.read(2))[0]
    elif n == 127:
        n = struct.unpack(">Q", reader.read(8))[0]
    return b0 & 0x0F, reader.read(n)


def test_the_layout_in_docs_is_the_default_rigs():
    from pathlib import Path

    from ambid.channels import RADIAL

    doc = Path(__file__).resolve().parents[2] / "docs" / "foxglove_layout.json"
    assert json.loads(doc.read_text()) == foxglove_layout(RADIAL)


def test_the_layout_has_a_bode_orbit_and_status_panel_for_any_layout():
    from ambid.channels import FIVE_AXIS, Layout

    lay = foxglove_layout(FIVE_AXIS)
    configs = lay["configById"]
    paths = [p["value"] for c in configs.values() for p in c.get("paths", [])]
    assert sum("/amb/live/frf/" in p and p.endswith(".magnitude_db[:]") for p in paths) == 25   # 5 x 5 entries
    assert sum(p.startswith("/amb/live/orbit/") for p in paths) == 2                        # bearings a, b
    assert any(c.get("topicPath", "").startswith("/amb/live/status") for c in configs.values())
    assert any(c.get("topicToRender") == "/amb/live/events" for c in configs.values())
    one = foxglove_layout(Layout(("z",)))
    assert not any("/orbit/" in p["value"] for c in one["configById"].values() for p in c.get("paths", []))


def test_a_session_faster_than_real_time_is_drawn_at_the_display_rate(session):
    """A simulated session runs many times faster than real time: the time signals and the orbits go out at most
    display_hz times per wall second (what a viewer draws), the stream's end always; every FRF estimate and the
    progress go out whole. The time signals as an envelope (no peak lost), the orbits of the blocks between
    counted, never queued."""
    from ambid_cli.bench.foxglove_client import follow

    d, x = session
    server = LiveServer(0, prefix="/amb/live", follower=SessionFollower(signal_rate_hz=1000.0),
                        display_hz=10.0).start()
    got: dict[str, list] = {}
    client = threading.Thread(target=lambda: asyncio.run(follow(
        server.url, lambda topic, t, m: got.setdefault(topic, []).append(m))), daemon=True)
    client.start()
    server.submit("design_message", "exp1", d, PRE, d.total_samples)
    k, end = 0, time.monotonic() + 30
    while not ({"/amb/live/signals", "/amb/live/progress"} <= set(got)) and time.monotonic() < end:
        server.submit("block", k, 1 / FS, NAMES, x[k:k + 500])   # a block every 0.1 s until they show: subscribed
        k += 500
        time.sleep(0.1)
    time.sleep(0.3)   # and to every channel advertised; what those blocks showed has come (a subscription in the
    server.drain(10.0)   # middle of a pair got half of it)
    shown_before = len(got["/amb/live/signals"])
    t0 = time.monotonic()
    for k in range(k, len(x), 500):   # as fast as the worker takes them: ~100 x real time
        server.submit("block", k, 1 / FS, NAMES, x[k:k + 500])
        server.drain(10.0)
    wall = time.monotonic() - t0
    figures = server.close()
    client.join(30)
    sig = got["/amb/live/signals"][shown_before:]
    assert len(sig) % 2 == 0 and 2 <= len(sig) <= 2 * (1 + 10.0 * wall + 3), (len(sig), wall)   # pairs, 10 a s
    # from the first sample shown on, every sample is in the envelope: its extremes are the signals' own
    rows = x[round(sig[0]["t_s"] * FS):]
    for c, name in enumerate(NAMES[:4]):
        assert [min(m[name] for m in sig), max(m[name] for m in sig)] == [rows[:, c].min(), rows[:, c].max()]
    assert figures["frames_thinned"] > 0                  # orbits of the blocks between two frames never sent
    assert sig[-1]["t_s"] == pytest.approx((len(x) - 1) / FS)   # the last sample shown
    final = [m for m in got["/amb/live/frf/y_a_y/u_a_x"] if m["complete"]]
    assert final and got["/amb/live/progress"][-1]["finished"]


def test_live_estimates_wait_their_turn_but_the_final_one_comes(session):
    """estimate_every_s: a record completed sooner than that after the last estimate waits; the final estimate
    (the whole experiment's, the session's) is always made."""
    d, x = session
    every, _ = _follow(d, x, block=250)
    f = SessionFollower(signal_rate_hz=500.0, orbit_points=50, estimate_every_s=3600.0)
    frames = f.design_message("exp1", d, PRE, d.total_samples)
    for k in range(0, len(x), 250):
        frames += f.block(k, 1 / FS, NAMES, x[k:k + 250])
    assert every.counts["estimates"] > 2 and f.counts["estimates"] == 2   # the first record's, and the final
    entry = [fr.message for fr in frames if fr.topic == "frf/y_a_y/u_a_x" and fr.message is not None]
    assert len(entry) == 2 and entry[-1]["complete"] and not entry[0]["complete"]
    np.testing.assert_array_equal(f.result.frf, every.result.frf)   # the same final estimate


def test_the_client_asks_again_for_a_channel_the_server_did_not_know_yet():
    """foxglove-sdk 0.30 can drop a subscription to a channel it has just advertised ("Unknown channel ID"):
    the bench's client (the viewer of the live view's tests and benchmark) asks for it again and gets its
    messages. The server here is a plain WebSocket one that drops the first subscription, as the SDK does."""
    import websockets
    from ambid_cli.bench.foxglove_client import follow

    asked: list[list[dict]] = []

    async def serve(ws):
        await ws.send(json.dumps({"op": "advertise", "channels": [
            {"id": 7, "topic": "/amb/live/progress", "encoding": "json", "schemaName": "p", "schema": "{}"}]}))
        async for raw in ws:
            subs = json.loads(raw)["subscriptions"]
            asked.append(subs)
            if len(asked) == 1:
                await ws.send(json.dumps({"op": "status", "level": 2, "message": "Unknown channel ID: 7"}))
            else:
                await ws.send(struct.pack("<BIQ", 1, subs[0]["id"], 5) + b'{"finished": true}')
                await ws.close()

    got: list[tuple] = []

    async def run():
        async with websockets.serve(serve, "127.0.0.1", 0, subprotocols=["foxglove.sdk.v1"]) as server:
            port = server.sockets[0].getsockname()[1]
            await follow(f"ws://127.0.0.1:{port}", lambda *m: got.append(m), connect_timeout_s=10.0)

    asyncio.run(asyncio.wait_for(run(), 30))
    assert [[s["channelId"] for s in a] for a in asked] == [[7], [7]]
    assert got == [("/amb/live/progress", 5, {"finished": True})]


class _Channel:
    """A channel of :class:`_RoutedLater`: it logs to the clients it is routed to."""

    def __init__(self, sdk, topic: str, cid: int):
        self.sdk, self.topic, self.cid, self.routed = sdk, topic, cid, set()

    def id(self):
        return self.cid

    def has_sinks(self):
        return bool(self.routed)

    def log(self, data, log_time=None):
        for client in list(self.routed):
            self.sdk.got.setdefault((client, self.topic), []).append(json.loads(data))


class _RoutedLater:
    """foxglove-sdk's order on a subscription, slowed down: ConnectedClient::on_subscribe calls the server
    listener's on_subscribe, and only then Context::subscribe_channels routes the channel to the client. A
    message logged in between misses that client. Here the routing waits for the test's word."""

    def __init__(self):
        self.channels, self.listener, self.got = {}, None, {}

    # the parts of the foxglove module LiveServer uses
    def Context(self):
        return None

    def Schema(self, **kw):
        return kw

    def start_server(self, server_listener, **kw):
        self.listener = server_listener
        return types.SimpleNamespace(port=1, stop=lambda: None)

    def Channel(self, topic, **kw):
        channel = _Channel(self, topic, len(self.channels) + 1)
        self.channels[topic] = channel
        return channel

    def subscribe(self, client: int, topic: str, held: bool) -> threading.Event | None:
        """The listener hears of it now; the channel is routed right after (as the SDK does) or, ``held``, once
        the returned event is set."""
        channel = self.channels[topic]
        self.listener.on_subscribe(types.SimpleNamespace(id=client), types.SimpleNamespace(id=channel.cid, topic=topic))
        if not held:
            channel.routed.add(client)
            return None
        route = threading.Event()
        threading.Thread(target=lambda: route.wait(10) and channel.routed.add(client), daemon=True).start()
        return route


def test_a_late_subscriber_gets_the_latest_message_once_the_sdk_routes_the_channel(session, monkeypatch):
    """The latest message goes to a client that subscribes after it was sent, also when the SDK routes the
    channel to the client a while after it told the server of the subscription (a busy machine: a live session's
    client once got no final FRF so), to a second client of a channel, and while the server closes."""
    import ambid.live.server as live_server

    d, x = session
    sdk = _RoutedLater()
    monkeypatch.setattr(live_server, "_foxglove", lambda: sdk)
    server = LiveServer(0, prefix="/amb/live", follower=SessionFollower(signal_rate_hz=100.0)).start()
    server.submit("design_message", "exp1", d, PRE, d.total_samples)
    for k in range(0, len(x), 1000):
        server.submit("block", k, 1 / FS, NAMES, x[k:k + 1000])
    assert server.drain(30.0)
    topic = "/amb/live/frf/y_a_y/u_a_x"
    assert topic in sdk.channels and not sdk.got   # sent while nobody subscribed

    def latest(client):
        end = time.monotonic() + 10
        while not sdk.got.get((client, topic)) and time.monotonic() < end:
            time.sleep(0.01)
        return sdk.got.get((client, topic), [])

    route = sdk.subscribe(1, topic, held=True)
    time.sleep(0.3)   # the worker has long woken to the subscription: the SDK has not routed the channel yet
    route.set()
    first = latest(1)
    assert len(first) == 1 and first[0]["complete"]
    first = first[0]   # the resends to the next clients go to it too (the SDK logs to each routed client)
    sdk.subscribe(2, topic, held=False)   # a second client: the channel has a sink (the first client's) already
    assert latest(2) == [first]
    other = "/amb/live/frf/y_a_x/u_a_y"   # as the server closes: the SDK routes a channel only after close()
    route = sdk.subscribe(3, other, held=True)   # began (a short session's channels come just before its end)
    closing = threading.Thread(target=server.close)
    closing.start()
    assert server._drained.wait(10)
    time.sleep(0.3)
    route.set()
    closing.join(10)
    assert not closing.is_alive()
    got = sdk.got.get((3, other), [])
    assert len(got) == 1 and got[0]["complete"] and got[0]["input"] == "u_a_y", got
    assert server.figures()["resent"] == 3
