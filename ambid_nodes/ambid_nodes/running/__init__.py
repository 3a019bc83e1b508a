"""Running a session: its plan (:mod:`ambid_nodes.running.plan`) and the ROS domain and namespace it runs
in (:mod:`ambid_nodes.running.domain`), shared by the layouts (composed: ``ambid_nodes.session``;
processes: ``ambid_nodes.session_processes``; graph and bench: ``ambid_nodes.graph``), none of which
imports another back."""
