"""The link to a real-time target: the bridge's UDP protocol and a reference target in Python
serving the simulated rig."""
