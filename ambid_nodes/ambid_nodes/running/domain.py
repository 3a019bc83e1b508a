"""Where a session's graph lives: its ROS domain and namespace (every layout and the supervisor read them)."""

from __future__ import annotations

import os

DEFAULT_NAMESPACE = "/amb"


def session_domain_id() -> int:
    """ROS_DOMAIN_ID if set, else one derived from this process, so sessions don't cross-talk."""
    env = os.environ.get("ROS_DOMAIN_ID")
    if env:
        return int(env)
    return 100 + os.getpid() % 100
