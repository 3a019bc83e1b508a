"""Running a session, one way: its plan (:mod:`ambid_nodes.running.plan`), the ROS domain and namespace it
runs in (:mod:`ambid_nodes.running.domain`), the :class:`~ambid_nodes.running.layout.Layout` interface
(:mod:`ambid_nodes.running.layout`) and its three implementations, composed, hardware and processes, and
:func:`ambid_nodes.running.run.run_session`, which picks one. Imports point down: run -> the layouts ->
layout -> plan -> domain; the layouts import the nodes, no node imports them."""
