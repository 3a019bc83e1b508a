"""Running a session, one way: its plan (:mod:`ambid_nodes.running.plan`), the ROS domain and namespace it
runs in (:mod:`ambid_nodes.running.domain`), the :class:`~ambid_nodes.running.layout.Layout` interface
(:mod:`ambid_nodes.running.layout`) and its three implementations, composed, hardware and processes,
:func:`ambid_nodes.running.run.run_session`, which picks one, and identify's job on top
(:mod:`ambid_nodes.running.identify`). Imports point down, in the order docs/architecture.md names (domain,
plan, layout, composed, hardware, processes, run, identify); the layouts import the nodes, no node imports
them (tests/core/test_architecture.py)."""
