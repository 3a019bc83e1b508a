"""Fixtures of the rclpy node tests: each test gets its own ROS context and DDS domain id."""

from __future__ import annotations

import itertools
import os
import time
from types import SimpleNamespace

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy missing: run the suite with ./launch_scripts/ambid test")
from rclpy._rclpy_pybind11 import InvalidHandle  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402

# domain ids 1..200, spread by process so concurrent test runs don't meet
_counter = itertools.count()


def next_domain_id() -> int:
    return 1 + (os.getpid() * 37 + next(_counter)) % 200


@pytest.fixture
def ros():
    """A fresh rclpy context on its own localhost-only domain with an EventsExecutor."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    domain = next_domain_id()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    executor = EventsExecutor(context=context)
    nodes = []
    names = set()  # (name, namespace) of every node added

    def add(node):
        nodes.append(node)
        names.add((node.get_name(), node.get_namespace()))
        executor.add_node(node)
        return node

    def graph() -> set:
        for n in nodes:  # any node the test has not destroyed itself
            try:
                return set(n.get_node_names_and_namespaces())
            except InvalidHandle:
                continue
        return set()

    def spin_until(predicate, timeout_s: float = 30.0) -> bool:
        end = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() > end:
                return False
            executor.spin_once(timeout_sec=0.05)
        return True

    yield SimpleNamespace(context=context, executor=executor, domain_id=domain, add=add, spin_until=spin_until)
    if nodes:
        # let DDS finish with peers that just left (a subprocess node the test stopped) before our
        # entities go: their unmatch events racing the destruction can crash the EventsExecutor
        # (ros2/rclpy#1644); bounded, a killed peer lingers until its lease expires
        spin_until(lambda: graph() <= names, 2.0)
        spin_until(lambda: False, 0.05)  # and the events already queued
    executor.shutdown()
    for n in nodes:
        n.destroy_node()
    rclpy.shutdown(context=context)


@pytest.fixture
def ros_env(ros):
    """Environment for subprocess nodes on the test's domain."""
    return dict(os.environ, ROS_DOMAIN_ID=str(ros.domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


@pytest.fixture(scope="module")
def ros_env_module():
    """Environment for subprocess nodes on a domain of their own, for a module's shared session."""
    return dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
