"""Fixtures of the rclpy node tests: each test gets its own ROS context and DDS domain id, waits for the graph
instead of racing it, and leaves no process behind.

Waiting for the graph. DDS discovery and matching take from milliseconds to seconds on a loaded machine, so a
test never assumes them: it builds the listening side first, waits with :func:`matched` (or ``ros.matched``)
until every publisher and subscription it relies on has its peers, and only then starts what it observes (the
controller, whose arrival starts the lock-step loop; an experiment; a flood).

Processes. Every subprocess a test starts goes through the ``procs`` fixture (or :func:`kill_tree` in a
``finally``): it runs in its own process group, and at the end of the test, passed or failed, the whole tree it
started (its children live in sessions of their own) is stopped: SIGCONT, SIGTERM, then SIGKILL.
"""

from __future__ import annotations

import os
import subprocess
import time
from types import SimpleNamespace

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy missing: run the suite with ./launch_scripts/ambid test")
from rclpy._rclpy_pybind11 import InvalidHandle  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.publisher import Publisher  # noqa: E402
from rclpy.subscription import Subscription  # noqa: E402

from domain_ids import next_domain_id  # noqa: E402,F401 - tests import it from here too
from proc_tree import kill_tree  # noqa: E402

MATCH_TIMEOUT_S = 60.0  # discovery on a loaded 2-core machine: seconds at worst, never this long
# the waits of the tests are bounds for liveness, never timing assertions: stretched on a loaded machine
TIMEOUT_SCALE = float(os.environ.get("AMBID_TEST_TIMEOUT_SCALE", "3"))
GRAPH_SETTLED_S = 1.0  # the ros fixture's teardown: a graph unchanged this long has no peer still leaving


def peers(entity) -> int:
    """Matched peers of a Publisher (subscriptions) or Subscription (publishers); anything with either count."""
    if isinstance(entity, Publisher) or hasattr(entity, "get_subscription_count"):
        return entity.get_subscription_count()
    return entity.get_publisher_count()


def _topics(node, kind: str) -> set[str]:
    return {e.topic_name for e in getattr(node, kind)}


def _expand(wanted, to=None) -> list[tuple[object, int, str]]:
    """(entity, at least n peers, label) from entities, (entity, n) pairs and nodes (each of its topic ends;
    with ``to``, only those meeting one of that node's)."""
    out = []
    for w in wanted:
        entity, n = w if isinstance(w, tuple) else (w, 1)
        if isinstance(entity, (Publisher, Subscription)) or not hasattr(entity, "publishers"):
            out.append((entity, n, getattr(entity, "topic_name", repr(entity))))
            continue
        # a node: every publisher and subscription it made on a topic of its own namespace (not the
        # parameter services' or rosout's, which nothing of a test waits for)
        ns = entity.get_namespace().rstrip("/") + "/"
        if to is None or hasattr(to, "publishers"):
            published = _topics(to, "publishers") if to is not None else None
            subscribed = _topics(to, "subscriptions") if to is not None else None
        else:  # topic names (relative to the node's namespace): the node's subscriptions to those
            published, subscribed = {t if t.startswith("/") else ns + t for t in to}, set()
        for kind in ("publishers", "subscriptions"):
            for e in getattr(entity, kind):
                topic = e.topic_name
                if not topic.startswith(ns) or "/_" in topic or topic.endswith("parameter_events"):
                    continue
                if to is not None and topic not in (subscribed if kind == "publishers" else published):
                    continue
                out.append((e, n, f"{entity.get_name()}: {topic}"))
    return out


def matched(ros, *wanted, to=None, timeout_s: float = MATCH_TIMEOUT_S) -> None:
    """Spin ``ros``'s executor until each wanted end has its peers; fail naming the ends still waiting.

    ``wanted``: publishers and subscriptions (at least one peer), ``(entity, n)`` pairs (at least n), or nodes
    (each of the node's publishers and subscriptions in its namespace at least one peer; with ``to=node``
    only those on a topic that node publishes or subscribes: ``matched(ros, spy, to=plant)`` waits until the
    spy hears every topic the plant publishes; with ``to=["displacement", ...]`` only its subscriptions to
    these topics, for a publisher in another process). Peers in other processes count too: these are DDS matches.
    """
    ends = _expand(wanted, to)
    if not ends:
        pytest.fail("matched(): nothing to wait for (no topic in common)")

    def missing() -> list[str]:
        return [f"{label} ({peers(e)} of {n})" for e, n, label in ends if peers(e) < n]

    end = time.monotonic() + timeout_s
    while missing() and time.monotonic() < end:
        ros.executor.spin_once(timeout_sec=0.05)
    if missing():
        pytest.fail(f"the graph did not match within {timeout_s:g} s: " + ", ".join(missing()))


@pytest.fixture
def procs():
    """``procs(args, **popen_kwargs)`` starts a subprocess in its own process group; at the end of the test,
    passed or failed, it and everything it started are stopped (:func:`kill_tree`)."""
    started: list[subprocess.Popen] = []

    def start(args, **kwargs) -> subprocess.Popen:
        kwargs.setdefault("start_new_session", True)
        p = subprocess.Popen(args, **kwargs)
        started.append(p)
        return p

    start.all = started
    yield start
    for p in reversed(started):
        kill_tree(p)


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

    def spin_until(predicate, timeout_s: float = 30.0, scale: bool = True) -> bool:
        # a wait for something to happen gets TIMEOUT_SCALE x its time: on a loaded machine it happens
        # late, not never (a short spin used as a pause, below 2 s, is kept as it is)
        end = time.monotonic() + (timeout_s * TIMEOUT_SCALE if timeout_s >= 2.0 and scale else timeout_s)
        while not predicate():
            if time.monotonic() > end:
                return False
            executor.spin_once(timeout_sec=0.05)
        return True

    def retire(*retired) -> None:
        # nodes taken out mid-test: their timers stopped, and the events already queued for them run while
        # they still exist (the EventsExecutor runs an event queued before its node was removed and destroyed:
        # InvalidHandle in a callback), then removed and destroyed
        for node in retired:
            for timer in node.timers:
                timer.cancel()
        spin_until(lambda: False, 0.1, scale=False)
        for node in retired:
            executor.remove_node(node)
            node.destroy_node()

    ns = SimpleNamespace(context=context, executor=executor, domain_id=domain, add=add, spin_until=spin_until,
                         retire=retire)
    ns.matched = lambda *wanted, to=None, timeout_s=MATCH_TIMEOUT_S: matched(ns, *wanted, to=to,
                                                                             timeout_s=timeout_s)
    yield ns
    if nodes:
        # let DDS finish with peers that just left (a subprocess node the test stopped) before our
        # entities go: their unmatch events racing the destruction can crash the EventsExecutor
        # (ros2/rclpy#1644); bounded, not scaled: a killed peer lingers until its lease expires, whatever the load.
        # The processes are gone by now (the procs fixture stops them first), and one that ended announced it
        # as it went: a graph standing still for GRAPH_SETTLED_S holds only killed peers, which no wait removes
        # (the drills' SIGKILLed nodes cost the whole 2 s each)
        seen = {"graph": None, "since": 0.0}

        def settled() -> bool:
            now, g = time.monotonic(), graph()
            if g <= names:
                return True
            if g != seen["graph"]:
                seen.update(graph=g, since=now)
            return now - seen["since"] >= GRAPH_SETTLED_S

        spin_until(settled, 2.0, scale=False)
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
