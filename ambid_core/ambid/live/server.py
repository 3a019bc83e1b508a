"""The live view's Foxglove WebSocket server: fed from any thread, never blocking it.

:class:`LiveServer` starts a WebSocket server of the ``foxglove-sdk``
package (``pip install './ambid_core[live]'``), which the Foxglove app opens
(*Open connection*, ``ws://HOST:PORT``). What a session publishes is handed
to :meth:`LiveServer.submit`, which only appends it to a bounded queue and
returns: a worker thread turns it into frames
(:class:`ambid.live.follower.SessionFollower`) and logs them, each topic on
a channel of the server, its messages JSON with a JSON schema
(:data:`ambid.live.frames.SCHEMAS`). So nothing a client does reaches the
caller:

* the queue holds at most ``queue_size`` items; when the worker falls behind
  the oldest block is dropped and counted (``dropped_frames``);
* a message is encoded only for a channel some client subscribes to, and the
  server keeps at most ``backlog`` messages per client (the SDK drops a slow
  client's oldest data messages: a client that never reads costs a bounded
  amount of memory);
* a client that subscribes late gets the channel's latest message once the SDK
  routes the channel to it (an FRF estimate comes only every few seconds),
  also while the server closes;
* the streams drawn as they come (the time signals, the orbits) are made
  only while a client subscribes to one of them, and sent at most
  ``display_hz`` times a wall second (:meth:`SessionFollower.display_frames
  <ambid.live.follower.SessionFollower.display_frames>`: the time signals'
  envelope since the last frames, no peak lost, and the latest block's
  orbits; the orbits of the blocks in between are counted,
  ``frames_thinned``), and once more at the end: a simulated session runs
  many times faster than real time, and a viewer draws some 30 frames a
  second. The FRF, levels, progress, statuses and events are all sent.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from typing import Any

from ambid.live.follower import SessionFollower
from ambid.live.frames import SCHEMAS, Frame

__all__ = ["LiveServer", "LiveUnavailable", "DEFAULT_PREFIX"]

#: Topic prefix of the live view's channels (below the session's namespace).
DEFAULT_PREFIX = "/amb/live"

#: Seconds the server waits, on closing, after it last sent a frame, before it stops: what the SDK has queued
#: for a client is sent by its own threads (which a busy machine may not run at once), and lost at its stop.
FLUSH_S = 0.5

#: Seconds after a second client subscribes to a channel before the channel's latest message is resent. The SDK
#: calls the listener's on_subscribe before it routes the channel to the client (foxglove-sdk's
#: ConnectedClient::on_subscribe, then Context::subscribe_channels; foxglove-sdk pull request 533, open): a message
#: logged in between misses the client. For a channel's first subscriber the routing shows (has_sinks()); for
#: another one nothing does.
SETTLE_S = 0.2

#: Seconds a resend waits for its channel to be routed to a client before it is given up.
RESEND_GIVE_UP_S = 10.0


class LiveUnavailable(RuntimeError):
    """The live view cannot start (foxglove-sdk missing, or the address cannot be bound)."""


def _foxglove():
    try:
        import foxglove
    except ImportError:
        raise LiveUnavailable("the live view needs the foxglove-sdk package: pip install './ambid_core[live]' "
                              "(./launch_scripts/ambid setup installs it)") from None
    return foxglove


class LiveServer:
    """A Foxglove WebSocket server showing one session.

    Parameters
    ----------
    port
        TCP port (0: any free one; :attr:`port` says which).
    host
        address to bind; 127.0.0.1 keeps it to this machine.
    follower
        what turns the session's messages into frames (default: indirect estimator).
    prefix
        topic prefix of the channels, e.g. ``/amb/live``.
    queue_size
        items the queue holds before it drops the oldest.
    backlog
        messages the server keeps per client before it drops that client's oldest.
    name
        the server's name, shown by Foxglove.
    display_hz
        the most times per wall second the streams drawn as they come (the time signals, the orbits) are sent;
        0: after every block.
    """

    def __init__(self, port: int, host: str = "127.0.0.1", follower: SessionFollower | None = None,
                 prefix: str = DEFAULT_PREFIX, queue_size: int = 64, backlog: int = 256,
                 name: str = "ambid live view", display_hz: float = 0.0) -> None:
        if not (isinstance(port, int) and 0 <= port <= 65535):
            raise ValueError(f"port must be an integer in 0..65535, got {port!r}")
        if queue_size < 1 or backlog < 1:
            raise ValueError(f"queue_size and backlog must be >= 1, got {queue_size}, {backlog}")
        if not display_hz >= 0:
            raise ValueError(f"display_hz must be >= 0, got {display_hz!r}")
        self._period = 1.0 / display_hz if display_hz > 0 else 0.0
        self._shown_at = -1e300                 # monotonic time the streams drawn as they come were last sent
        self._sent_at = -1e300                  # monotonic time a frame was last handed to the SDK
        self.follower = follower if follower is not None else SessionFollower()
        self.prefix = "/" + prefix.strip("/")
        self.host, self._port, self.name = host, port, name
        self.backlog = backlog
        self.queue_size = queue_size
        self._queue: deque = deque()
        self._wake = threading.Event()
        self._lock = threading.Lock()          # guards the counters shared with submit()
        self._closing = False
        self._resend: dict[int, tuple[float, bool]] = {}  # channel id -> (when subscribed, its first subscriber)
        self._subscribers: dict[int, int] = {}             # channel id -> subscriptions the listener saw
        self._drained = threading.Event()      # the worker processed what was queued before close()
        self._stop = False                     # close(): the worker stops serving late subscribers
        self._channels: dict[str, Any] = {}    # topic -> foxglove Channel
        self._by_id: dict[int, str] = {}
        self._latest: dict[str, Frame] = {}
        self._clients: set[int] = set()
        self.counts = {"submitted": 0, "dropped_frames": 0, "frames": 0, "frames_sent": 0, "bytes_sent": 0,
                       "resent": 0, "resends_given_up": 0, "worker_errors": 0, "stop_timed_out": 0}
        self.errors: list[str] = []
        self._server = None
        self._context = None
        self._thread: threading.Thread | None = None

    # ---- life -----------------------------------------------------------------------------------
    def start(self) -> "LiveServer":
        """Bind the server and start the worker.

        Raises
        ------
        LiveUnavailable
            foxglove-sdk is missing, or ``host:port`` cannot be bound (one line saying so).
        """
        fg = _foxglove()
        self._context = fg.Context()
        try:
            self._server = fg.start_server(name=self.name, host=self.host, port=self._port, context=self._context,
                                           server_listener=_Listener(self), message_backlog_size=self.backlog)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types for bind failures
            raise LiveUnavailable(f"the live view cannot listen on {self.host}:{self._port} ({exc}); choose "
                                  "another port with --live PORT, or free this one") from None
        self._port = self._server.port
        self._thread = threading.Thread(target=self._work, name="ambid-live", daemon=True)
        self._thread.start()
        return self

    @property
    def port(self) -> int:
        """The port the server listens on (after :meth:`start`)."""
        return self._port

    @property
    def url(self) -> str:
        """``ws://host:port``, what the Foxglove app opens."""
        return f"ws://{self.host}:{self.port}"

    def close(self, timeout_s: float = 5.0) -> dict:
        """Process what is queued (for at most ``timeout_s``), give the frames sent last :data:`FLUSH_S` to
        reach the clients while still serving late subscribers, then stop the worker and the server; the
        figures."""
        self._closing = True
        self._wake.set()
        end = time.monotonic() + timeout_s
        if self._thread is not None:
            self._drained.wait(timeout_s)
        if self._server is not None:
            # the SDK's stop() abandons what is still queued for a client (foxglove-sdk's poller sends Close
            # without draining its queue): the frames sent last (the stream's end, the final FRF) get
            # FLUSH_S to leave first. On a fast machine, or one core, they were all lost. A client that
            # subscribes meanwhile (a short session's channels are advertised just before its end) still gets
            # each channel's latest message: the worker serves it, and its resend is waited for.
            flush_end = max(end, time.monotonic() + FLUSH_S)
            while time.monotonic() < flush_end:
                with self._lock:
                    pending = bool(self._resend)
                left = self._sent_at + FLUSH_S - time.monotonic()
                if left <= 0 and not pending:
                    break
                time.sleep(min(max(left, 0.0), 0.05) if not pending else 0.02)
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(max(end - time.monotonic(), 0.1))
        if self._server is not None:
            # and then it waits for each client's socket to take the Close, without a time limit: a client
            # that stopped reading would hold the session's end. Stopped on a thread of its own (the SDK lets
            # go of the GIL there), waited for a while, then left to the exit.
            stopper = threading.Thread(target=self._server.stop, name="ambid-live-stop", daemon=True)
            stopper.start()
            stopper.join(min(timeout_s, 2.0))
            self.counts["stop_timed_out"] = int(stopper.is_alive())
            self._server = None
        return self.figures()

    # ---- input (any thread) -----------------------------------------------------------------------
    def submit(self, kind: str, *args: Any) -> None:
        """Hand over one message of the session: ``kind`` names the follower's method
        (``design_message``, ``block``, ``status_message``, ``event_message``), ``args`` its arguments.
        Returns at once; when the queue is full its oldest block (else its oldest item) is dropped and
        counted."""
        with self._lock:
            q = self._queue
            if len(q) >= self.queue_size:
                # a block goes first (its loss is a gap the FRF handles); a design, status or event stays
                victim = next((i for i, (k, _) in enumerate(q) if k == "block"), 0)
                del q[victim]
                self.counts["dropped_frames"] += 1
            q.append((kind, args))
            self.counts["submitted"] += 1
        self._wake.set()

    def figures(self) -> dict:
        """Counters of the server (submitted, dropped_frames, frames, frames_sent, bytes_sent, resent: latest
        messages sent again to late subscribers, clients) and of the follower (blocks, lost_blocks, lost_samples, records, ...)."""
        with self._lock:
            c = dict(self.counts)
        return {**self.follower.figures(), **c, "clients": len(self._clients), "channels": len(self._channels),
                "url": self.url, "problems": (self.follower.problems + self.errors)[-5:]}

    def drain(self, timeout_s: float = 5.0) -> bool:
        """Wait until the worker has processed everything submitted so far; False on timeout."""
        done = threading.Event()
        self.submit("_mark", done)
        return done.wait(timeout_s)

    # ---- worker ---------------------------------------------------------------------------------
    def _work(self) -> None:
        while not self._stop:
            self._wake.wait(self._next_wait())
            self._wake.clear()
            while True:
                with self._lock:
                    item = self._queue.popleft() if self._queue else None
                if item is None:
                    break
                kind, args = item
                if kind == "_mark":
                    args[0].set()
                    continue
                try:
                    if kind == "block":
                        self.follower.display = self._display_wanted()
                    frames = getattr(self.follower, kind)(*args)
                    if kind == "block" and not self._period:
                        frames += self.follower.display_frames()
                    for frame in frames:
                        self._log(frame)
                except Exception as exc:  # noqa: BLE001 - a bad message must not stop the live view
                    self.counts["worker_errors"] += 1
                    self.errors.append(f"{kind}: {type(exc).__name__}: {exc}")
                    del self.errors[:-20]
            self._serve_late_subscribers()
            if not self._drained.is_set():
                final = self._closing and not self._queue
                self._display(final)
                if final:
                    self._drained.set()

    def _serve_late_subscribers(self) -> None:
        """Resend each newly subscribed channel's latest message, once the SDK routes the channel to the client."""
        now = time.monotonic()
        with self._lock:   # the SDK's threads add to it (_subscribed)
            pending = list(self._resend.items())
        for cid, (t, first) in pending:
            topic = self._by_id.get(cid)
            channel = self._channels.get(topic)
            routed = channel is not None and (channel.has_sinks() if first else now - t >= SETTLE_S)
            if not routed and now - t <= RESEND_GIVE_UP_S:
                continue   # asked again at the worker's next wake
            with self._lock:   # unless the channel was subscribed to again meanwhile
                if self._resend.get(cid) == (t, first):
                    del self._resend[cid]
            if not routed:
                self.counts["resends_given_up"] += 1
            elif topic in self._latest:
                self._send(channel, self._latest[topic])
                self.counts["resent"] += 1

    def _display_wanted(self) -> bool:
        """Whether a client subscribes to a stream drawn as it comes (or one is not known or advertised yet)."""
        topics = self.follower.display_topics
        return not topics or any(t not in self._channels or self._channels[t].has_sinks() for t in topics)

    def _next_wait(self) -> float:
        """Seconds the worker may sleep: a little while a resend waits for its channel's routing, until the held
        streams' turn, else half a second."""
        if self._resend:
            return 0.02
        if self.follower.display_pending:
            return max(self._shown_at + self._period - time.monotonic(), 0.0)
        return 0.5

    def _display(self, final: bool) -> None:
        """The streams drawn as they come, when their turn has come (``final``: what is held, at once)."""
        now = time.monotonic()
        if final or now - self._shown_at >= self._period:
            frames = self.follower.display_frames(final)
            if frames:
                self._shown_at = now
            for frame in frames:
                self._log(frame)

    def _log(self, frame: Frame) -> None:
        channel = self._channels.get(frame.topic)
        if channel is None:
            channel = self._channel(frame)
        if frame.message is None:   # advertised only
            return
        self.counts["frames"] += 1
        self._latest[frame.topic] = frame
        if channel.has_sinks():   # nobody subscribes: not even encoded
            self._send(channel, frame)

    def _send(self, channel, frame: Frame) -> None:
        message = frame.message
        if frame.schema_name == "ambid.live.Progress":
            message = dict(message, dropped_frames=self.counts["dropped_frames"])
        data = json.dumps(message, allow_nan=False, separators=(",", ":")).encode()
        channel.log(data, log_time=frame.t_ns)
        self._sent_at = time.monotonic()
        self.counts["frames_sent"] += 1
        self.counts["bytes_sent"] += len(data)

    def _channel(self, frame: Frame):
        fg = _foxglove()
        schema = fg.Schema(name=frame.schema_name, encoding="jsonschema",
                           data=json.dumps(SCHEMAS[frame.schema_name]).encode())
        channel = fg.Channel(f"{self.prefix}/{frame.topic}", schema=schema, message_encoding="json",
                             context=self._context)
        self._channels[frame.topic] = channel
        self._by_id[channel.id()] = frame.topic
        return channel

    def _subscribed(self, client_id: int, channel_id: int) -> None:
        with self._lock:
            self._clients.add(client_id)
            n = self._subscribers.get(channel_id, 0)
            self._subscribers[channel_id] = n + 1
            self._resend[channel_id] = (time.monotonic(), n == 0)
        self._wake.set()

    def _unsubscribed(self, channel_id: int) -> None:
        with self._lock:
            n = max(self._subscribers.get(channel_id, 0) - 1, 0)
            self._subscribers[channel_id] = n
            if n == 0:   # its client left (or unsubscribed) before the resend: nobody to wait for
                self._resend.pop(channel_id, None)


class _Listener:
    """The SDK's server listener: called on the SDK's threads, so it only notes and wakes the worker."""

    def __init__(self, server: LiveServer) -> None:
        self._server = server

    def on_subscribe(self, client, channel) -> None:
        self._server._subscribed(client.id, channel.id)

    def on_unsubscribe(self, client, channel) -> None:
        self._server._unsubscribed(channel.id)
