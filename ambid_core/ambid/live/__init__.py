"""The live view: a running session in the Foxglove app, over the Foxglove WebSocket protocol.

- :mod:`.frames`: what is shown, as JSON messages with their schemas (Bode per FRF entry, levels,
  time signals, orbits, progress, status, events).
- :mod:`.follower`: a session followed from what it publishes (design, blocks, status, events):
  its own streaming FRF, estimated after every record.
- :mod:`.server`: the Foxglove WebSocket server (foxglove-sdk, the optional ``live`` dependency),
  fed from any thread through a bounded queue.
- :mod:`.layout`: the Foxglove layout of the Bode, orbit and status panels for a session's channels.

No ROS here: ``ambid_nodes.live_view`` is the node that feeds a :class:`~ambid.live.server.LiveServer`.
"""
